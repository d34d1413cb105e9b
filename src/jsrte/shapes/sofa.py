"""Procedural sofas (metres; +y up, width along x, the seat's open front towards -z).

Every sofa is a base (on legs or a plinth down to the floor), one to three seat cushions
(separate slabs), a back frame, optional back cushions and optional arms.
Styles: track arms (boxes) on legs, rolled arms (a box capped by a roll), tuxedo (arms as
high as the back) on a plinth, armless on legs, and mid-century (tall tapered legs, thin
open arms on posts, thin back).
"""

from __future__ import annotations

import numpy as np

from jsrte.shapes.params import ParamSampler
from jsrte.shapes.parts import (
    CLEARANCE_M,
    FLOOR_SINK_M,
    OVERLAP_M,
    SEGMENTS,
    Parts,
    bar,
    box,
    placed,
    rod,
    rot_x,
    rounded_slab,
    span_box,
)

STYLES = ("track_arm", "rolled_arm", "tuxedo", "armless", "mid_century")


def generate(rng: np.random.Generator) -> tuple[Parts, str, dict]:
    """Draw one sofa: its parts, style name and every parameter drawn."""
    s = ParamSampler(rng)
    style = s.choice("style", STYLES)
    parts = Parts()
    _build(parts, s, style)
    return parts, style, s.params


def _build(parts: Parts, s: ParamSampler, style: str) -> None:
    n_seats = s.integer("n_seats", 1, 3)
    seat_w = s.uniform("seat_unit_width_m", 0.55, 0.70)
    has_arms = style != "armless"
    if style == "mid_century":
        arm_w = s.uniform("arm_width_m", 0.05, 0.08)
    elif has_arms:
        arm_w = s.uniform("arm_width_m", 0.12, 0.25)
    else:
        arm_w = 0.0
    inner_w = n_seats * seat_w
    width = s.set("width_m", round(inner_w + 2 * arm_w, 4))
    depth = s.uniform("depth_m", 0.78, 1.0)
    seat_h = s.uniform("seat_height_m", 0.40, 0.47)
    cushion_t = s.uniform("seat_cushion_thickness_m", 0.10, 0.18)
    back_h = s.uniform("back_height_m", 0.72, 0.95)
    back_t = s.uniform("back_thickness_m", 0.08 if style == "mid_century" else 0.14, 0.24)
    on_legs = style in ("track_arm", "armless", "mid_century") or (
        style == "rolled_arm" and s.flag("rolled_on_legs", 0.5))
    s.set("on_legs", on_legs)
    leg_h = s.uniform("leg_height_m", 0.15 if style == "mid_century" else 0.05,
                      0.25 if style == "mid_century" else 0.15) if on_legs else 0.0
    s.set("leg_height_m", leg_h)
    base_top = seat_h - cushion_t
    base_bottom = leg_h
    if base_top - base_bottom < 0.06:  # keep a real frame under the cushions
        base_bottom = base_top - 0.06
        s.set("leg_height_m", round(base_bottom, 4))
        leg_h = base_bottom
    zf, zb = -depth / 2, depth / 2
    # base frame (full width), back frame at the rear
    parts.add(span_box((-width / 2, base_bottom if on_legs else -FLOOR_SINK_M, zf),
                       (width / 2, base_top + OVERLAP_M, zb)))
    parts.add(span_box((-inner_w / 2 - OVERLAP_M, base_top - OVERLAP_M, zb - back_t),
                       (inner_w / 2 + OVERLAP_M, back_h, zb)))
    _seat_cushions(parts, s, n_seats, seat_w, base_top, seat_h, zf, zb - back_t)
    if s.flag("back_cushions", 0.0 if style == "mid_century" else 0.7):
        _back_cushions(parts, s, n_seats, inner_w, seat_h, back_h, zb - back_t)
    if on_legs:
        _legs(parts, s, width, depth, leg_h, tapered=style == "mid_century")
    if style == "track_arm":
        arm_h = s.uniform("arm_height_m", 0.55, 0.68)
        parts.add_pair(span_box((inner_w / 2, base_bottom if on_legs else -FLOOR_SINK_M, zf),
                                (width / 2, arm_h, zb)))
    elif style == "rolled_arm":
        arm_h = s.uniform("arm_height_m", 0.55, 0.66)
        roll_r = min(arm_w * s.uniform("roll_ratio", 0.55, 0.7), 0.12)
        x = inner_w / 2 + arm_w / 2
        bottom = base_bottom if on_legs else -FLOOR_SINK_M
        parts.add_pair(span_box((inner_w / 2, bottom, zf + 0.02), (width / 2, arm_h - roll_r, zb)))
        parts.add_pair(rod((x, arm_h - roll_r, zf), (x, arm_h - roll_r, zb), roll_r),
                       placed(_disc_x(roll_r * 1.05, 0.04), None, (x, arm_h - roll_r, zf + 0.02)))
    elif style == "tuxedo":
        parts.add_pair(span_box((inner_w / 2, -FLOOR_SINK_M, zf), (width / 2, back_h, zb)))
    elif style == "mid_century":
        _open_arms(parts, s, inner_w, arm_w, base_top, zf, zb - back_t)


def _disc_x(radius: float, thickness: float) -> object:
    """A round plate facing -z (the front face of a rolled arm)."""
    from manifold3d import Manifold

    return Manifold.cylinder(thickness, radius, radius, SEGMENTS, True)


def _seat_cushions(parts: Parts, s: ParamSampler, n: int, seat_w: float, base_top: float,
                   seat_h: float, zf: float, z_back: float) -> None:
    """``n`` cushion slabs side by side on the base, separated by shallow grooves."""
    gap = s.uniform("cushion_gap_m", 0.005, 0.015)
    overhang = s.uniform("cushion_front_overhang_m", 0.0, 0.03)
    t = seat_h - base_top
    z0, z1 = zf - overhang, z_back + OVERLAP_M
    for i in range(n):
        x = (i - (n - 1) / 2) * seat_w
        slab = rounded_slab((seat_w - gap, t + OVERLAP_M, z1 - z0),
                            (x, base_top + (t - OVERLAP_M) / 2, (z0 + z1) / 2), 0.35 * t)
        if i == (n - 1) / 2:
            parts.add(slab)
        elif x > 0:
            parts.add_pair(slab)


def _back_cushions(parts: Parts, s: ParamSampler, n: int, inner_w: float, seat_h: float,
                   back_h: float, z_back: float) -> None:
    """Back cushions leaning on the back frame, one per seat or one long one."""
    ct = s.uniform("back_cushion_thickness_m", 0.10, 0.18)
    top = back_h - s.uniform("back_cushion_drop_m", -0.03, 0.06)
    tilt = s.uniform("back_cushion_tilt_deg", 5.0, 15.0, digits=2)
    single = s.flag("single_back_cushion", 0.25)
    count = 1 if single else n
    cw = inner_w / count
    height = top - seat_h + OVERLAP_M
    for i in range(count):
        x = (i - (count - 1) / 2) * cw
        local = rounded_slab((cw - 0.01, height, ct), (x, height / 2, -ct / 2 + 0.02), 0.3 * ct)
        slab = placed(local, rot_x(tilt), (0.0, seat_h - OVERLAP_M, z_back))
        if i == (count - 1) / 2:
            parts.add(slab)
        elif x > 0:
            parts.add_pair(slab)


def _legs(parts: Parts, s: ParamSampler, width: float, depth: float, leg_h: float, *,
          tapered: bool) -> None:
    """Four legs (six on wide sofas) under the base; tapered and splayed for mid-century."""
    size = s.uniform("leg_size_m", 0.035, 0.06)
    inset = s.uniform("leg_inset_m", 0.02, 0.08)
    x, z = width / 2 - inset - size / 2, depth / 2 - inset - size / 2
    top = leg_h + OVERLAP_M
    splay = s.uniform("leg_splay_m", 0.01, 0.04) if tapered else 0.0
    for zz in (-z, z):
        if tapered:
            foot = (x + splay, -FLOOR_SINK_M, zz + np.sign(zz) * splay)
            parts.add_pair(rod(foot, (x, top, zz), max(0.015, size / 2 * 0.6), size / 2))
        else:
            parts.add_pair(box((size, top + FLOOR_SINK_M, size), (x, (top - FLOOR_SINK_M) / 2, zz)))
    if width > 1.8:
        for zz in (-z, z):
            parts.add(box((size, top + FLOOR_SINK_M, size), (0.0, (top - FLOOR_SINK_M) / 2, zz)))


def _open_arms(parts: Parts, s: ParamSampler, inner_w: float, arm_w: float, base_top: float,
               zf: float, z_back: float) -> None:
    """Thin armrests on a front post, reaching back into the back frame."""
    arm_h = s.uniform("arm_height_m", 0.55, 0.65)
    at = s.uniform("arm_thickness_m", 0.03, 0.05)
    x = inner_w / 2 + arm_w / 2
    z_post = zf + s.uniform("arm_post_inset_m", 0.03, 0.10)
    parts.add_pair(box((arm_w, at, z_back - zf + 0.03), (x, arm_h - at / 2, (zf + z_back) / 2 + 0.015)))
    parts.add_pair(bar((x, base_top - 0.05, z_post), (x, arm_h - at + OVERLAP_M, z_post),
                       arm_w - 2 * CLEARANCE_M, max(0.03, arm_w)))  # not flush with the armrest's sides
