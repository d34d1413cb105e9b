"""Procedural beds (metres; +y up, width along x, headboard at +z, the foot end towards -z).

Every bed is a mattress slab on a base with a headboard. Styles: a frame on legs with a
headboard only, a frame with head- and footboard on corner posts, a box (divan) base down
to the floor, a low platform wider than the mattress, and a four-poster with top rails.
Sizes run from single (0.9 m) to king (1.9 m) mattresses.
"""

from __future__ import annotations

import numpy as np

from jsrte.shapes.params import ParamSampler
from jsrte.shapes.parts import (
    FLOOR_SINK_M,
    OVERLAP_M,
    Parts,
    box,
    rod,
    rounded_slab,
    span_box,
)

STYLES = ("headboard_legs", "head_footboard", "box_base", "platform", "four_poster")
MATTRESS_WIDTHS_M = (0.9, 1.2, 1.4, 1.6, 1.8)
"""Common mattress widths (single to king); a small random deviation is added."""


def generate(rng: np.random.Generator) -> tuple[Parts, str, dict]:
    """Draw one bed: its parts, style name and every parameter drawn."""
    s = ParamSampler(rng)
    style = s.choice("style", STYLES)
    parts = Parts()
    _build(parts, s, style)
    return parts, style, s.params


def _build(parts: Parts, s: ParamSampler, style: str) -> None:
    nominal = float(MATTRESS_WIDTHS_M[s.integer("size_index", 0, len(MATTRESS_WIDTHS_M) - 1)])
    mw = s.uniform("mattress_width_m", nominal - 0.02, nominal + 0.05)
    ml = s.uniform("mattress_length_m", 1.9, 2.1)
    mt = s.uniform("mattress_thickness_m", 0.16, 0.30)
    frame_t = s.uniform("frame_thickness_m", 0.03, 0.06)  # side rails / headboard board
    head_t = s.uniform("headboard_thickness_m", 0.04, 0.10)
    if style == "platform":
        base_top = s.uniform("base_top_m", 0.12, 0.25)
        margin = s.uniform("platform_margin_m", 0.05, 0.20)
    elif style == "box_base":
        base_top = s.uniform("base_top_m", 0.25, 0.40)
        margin = 0.0
    else:
        base_top = s.uniform("base_top_m", 0.25, 0.40)
        margin = frame_t
    width = mw + 2 * margin
    zb = ml / 2 + margin  # the headboard's front face
    zf = -ml / 2 - margin
    parts.add(rounded_slab((mw, mt + OVERLAP_M, ml), (0, base_top + (mt - OVERLAP_M) / 2, 0),
                           s.uniform("mattress_rounding_m", 0.02, 0.06)))
    head_h = s.uniform("headboard_height_m", base_top + mt + 0.25, base_top + mt + 0.75)
    if style in ("headboard_legs", "head_footboard", "four_poster"):
        _frame(parts, s, style, width, zf, zb, base_top, mt, frame_t, head_t, head_h)
    else:
        bottom = -FLOOR_SINK_M
        if style == "platform" and s.flag("recessed_plinth", 0.6):
            inset = s.uniform("plinth_inset_m", 0.08, 0.2)
            plinth_top = base_top - s.uniform("platform_thickness_m", 0.05, 0.10)
            parts.add(span_box((-width / 2 + inset, bottom, zf + inset),
                               (width / 2 - inset, plinth_top + OVERLAP_M, zb - inset)))
            bottom = plinth_top
        parts.add(span_box((-width / 2, bottom, zf), (width / 2, base_top + OVERLAP_M, zb)))
        hw = width + 2 * s.uniform("headboard_overhang_m", 0.0, 0.12)
        parts.add(span_box((-hw / 2, -FLOOR_SINK_M if style == "box_base" else base_top - 0.05,
                            zb - OVERLAP_M),
                           (hw / 2, head_h, zb + head_t)))


def _frame(parts: Parts, s: ParamSampler, style: str, width: float, zf: float, zb: float,
           base_top: float, mt: float, frame_t: float, head_t: float, head_h: float) -> None:
    """A bed frame: side and end rails, slat deck, headboard, legs/posts, footboard, canopy."""
    rail_h = s.uniform("rail_height_m", 0.12, 0.22)
    leg = s.uniform("leg_size_m", 0.04, 0.08) if style == "headboard_legs" else \
        s.uniform("post_size_m", 0.06, 0.10)
    y0 = base_top - rail_h
    # deck under the mattress (rails + slats as one board) and the side / foot rails
    parts.add(span_box((-width / 2, base_top - 0.03, zf), (width / 2, base_top + OVERLAP_M, zb)))
    parts.add_pair(span_box((width / 2 - frame_t, y0, zf), (width / 2, base_top + OVERLAP_M, zb)))
    parts.add(span_box((-width / 2, y0, zf), (width / 2, base_top + OVERLAP_M, zf + frame_t)))
    head_w = width + (2 * leg if style != "headboard_legs" else 0.0)
    parts.add(span_box((-head_w / 2, y0, zb - OVERLAP_M), (head_w / 2, head_h, zb + head_t)))
    grip = 0.015  # how far corner posts reach into the rails
    x = width / 2 - leg / 2 if style == "headboard_legs" else width / 2 + leg / 2 - grip
    z_front = zf + leg / 2 if style == "headboard_legs" else zf - leg / 2 + grip
    z_back = zb + head_t / 2
    if style == "headboard_legs":
        parts.add_pair(box((leg, y0 + OVERLAP_M + FLOOR_SINK_M, leg),
                           (x, (y0 + OVERLAP_M - FLOOR_SINK_M) / 2, z_front)))
        parts.add_pair(span_box((head_w / 2 - leg, -FLOOR_SINK_M, zb - OVERLAP_M),
                                (head_w / 2, y0 + OVERLAP_M, zb + head_t)))
        return
    foot_h = s.uniform("footboard_height_m", base_top + 0.6 * mt,
                       min(base_top + mt + 0.35, head_h - 0.15))
    head_post_h = head_h + s.uniform("post_above_board_m", 0.0, 0.08)
    foot_post_h = foot_h + s.uniform("post_above_footboard_m", 0.0, 0.08)
    if style == "four_poster":
        head_post_h = foot_post_h = s.uniform("canopy_height_m", 1.8, 2.2)
    round_posts = s.flag("round_posts", 0.5)
    for z, h in ((z_back, head_post_h), (z_front, foot_post_h)):
        if round_posts:
            parts.add_pair(rod((x, -FLOOR_SINK_M, z), (x, h, z), leg / 2))
        else:
            parts.add_pair(box((leg, h + FLOOR_SINK_M, leg), (x, (h - FLOOR_SINK_M) / 2, z)))
    parts.add(span_box((-x, y0, z_front - frame_t / 2 - 0.01), (x, foot_h, z_front + frame_t / 2)))
    if style == "four_poster":
        top = head_post_h - 0.04
        rail = 0.05
        parts.add_pair(span_box((x - rail / 2, top - rail, z_front), (x + rail / 2, top, z_back)))
        for z in (z_front, z_back):
            parts.add(span_box((-x, top - rail, z - rail / 2), (x, top, z + rail / 2)))
