"""Procedural tables (metres; +y up, width along x, front towards -z).

Styles: four legs with an apron, a pedestal (round column on a disc or cross foot), a
trestle (two end frames and a stretcher), a low coffee table (optionally with a shelf),
and a panel table (two solid side panels, optionally a modesty panel at the back).
Tops are rectangular or round (four-leg, pedestal, coffee); heights are dining/desk or low.
"""

from __future__ import annotations

import numpy as np

from jsrte.shapes.params import ParamSampler
from jsrte.shapes.parts import (
    CLEARANCE_M,
    FLOOR_SINK_M,
    OVERLAP_M,
    Parts,
    bar,
    box,
    disc,
    rod,
    span_box,
)

STYLES = ("four_leg_apron", "pedestal", "trestle", "coffee", "panel")


def generate(rng: np.random.Generator) -> tuple[Parts, str, dict]:
    """Draw one table: its parts, style name and every parameter drawn."""
    s = ParamSampler(rng)
    style = s.choice("style", STYLES)
    parts = Parts()
    _BUILDERS[style](parts, s)
    return parts, style, s.params


def _top(parts: Parts, s: ParamSampler, *, height: tuple[float, float], round_top: bool,
         width: tuple[float, float], depth_ratio: tuple[float, float] = (0.5, 0.75),
         ) -> tuple[float, float, float, float]:
    """Add the top; returns (height, width along x, depth along z, thickness) in m."""
    h = s.uniform("height_m", *height)
    t = s.uniform("top_thickness_m", 0.025, 0.05)
    s.set("top_shape", "round" if round_top else "rectangular")
    if round_top:
        w = s.uniform("top_diameter_m", *width)
        d = w
        parts.add(disc((0, h - t / 2, 0), w / 2, t, segments=64))
    else:
        w = s.uniform("top_width_m", *width)
        d = s.uniform("top_depth_m", max(0.45, w * depth_ratio[0]), min(1.1, max(0.5, w * depth_ratio[1])))
        parts.add(box((w, t, d), (0, h - t / 2, 0)))
    return h, w, d, t


def _legs(parts: Parts, s: ParamSampler, xl: float, zl: float, y_top: float, *,
          round_legs: bool, size: float, taper: float = 1.0) -> None:
    """Four vertical legs at (+-xl, +-zl) from below the floor to ``y_top``."""
    for z in (-zl, zl):
        p0, p1 = (xl, -FLOOR_SINK_M, z), (xl, y_top, z)
        if round_legs:
            parts.add_pair(rod(p0, p1, max(0.015, size / 2 * taper), size / 2))
        else:
            parts.add_pair(bar(p0, p1, size))


def _four_leg_apron(parts: Parts, s: ParamSampler) -> None:
    round_top = s.flag("round_top", 0.3)
    h, w, d, t = _top(parts, s, height=(0.70, 0.77), round_top=round_top,
                      width=(0.85, 1.2) if round_top else (0.8, 1.9))
    lw = s.uniform("leg_size_m", 0.04, 0.08)
    round_legs = s.flag("round_legs", 0.4)
    taper = s.uniform("leg_taper", 0.55, 1.0) if round_legs else 1.0
    inset = s.uniform("leg_inset_m", 0.02, 0.08)
    if round_top:  # legs on a square inscribed in the circle
        half = w / 2 / np.sqrt(2) - inset
        xl = zl = half - lw / 2
    else:
        xl, zl = w / 2 - inset - lw / 2, d / 2 - inset - lw / 2
    y_leg = h - t + OVERLAP_M
    _legs(parts, s, xl, zl, y_leg, round_legs=round_legs, size=lw, taper=taper)
    apron_h = s.uniform("apron_height_m", 0.06, 0.12)
    at = s.uniform("apron_thickness_m", 0.025, 0.035)
    y0, y1 = h - t - apron_h, h - t + OVERLAP_M
    parts.add(span_box((-xl, y0, -zl - at / 2), (xl, y1, -zl + at / 2)),
              span_box((-xl, y0, zl - at / 2), (xl, y1, zl + at / 2)))
    parts.add_pair(span_box((xl - at / 2, y0, -zl), (xl + at / 2, y1, zl)))
    if s.flag("stretchers", 0.3):
        y = s.uniform("stretcher_height_m", 0.10, 0.25)
        parts.add_pair(bar((xl, y, -zl), (xl, y, zl), 0.03))
        parts.add(bar((-xl, y, 0.0), (xl, y, 0.0), 0.03))


def _pedestal(parts: Parts, s: ParamSampler) -> None:
    round_top = s.flag("round_top", 0.7)
    h, w, d, t = _top(parts, s, height=(0.70, 0.76), round_top=round_top, width=(0.7, 1.2),
                      depth_ratio=(0.7, 1.0))
    col_r = s.uniform("column_radius_m", 0.04, 0.09)
    foot = s.choice("foot", ("disc", "cross"))
    foot_t = s.uniform("foot_thickness_m", 0.03, 0.06)
    reach = s.uniform("foot_radius_m", 0.22, min(0.38, 0.45 * min(w, d)))
    if foot == "disc":
        parts.add(disc((0, foot_t / 2 - FLOOR_SINK_M / 2, 0), reach, foot_t + FLOOR_SINK_M,
                       segments=48))
    else:
        fw = s.uniform("foot_width_m", 0.05, 0.09)
        size_y = foot_t + FLOOR_SINK_M
        parts.add(box((2 * reach, size_y, fw), (0, foot_t / 2 - FLOOR_SINK_M / 2, 0)),
                  box((fw, size_y, 2 * reach), (0, foot_t / 2 - FLOOR_SINK_M / 2, 0)))
    parts.add(rod((0, foot_t - OVERLAP_M, 0), (0, h - t + OVERLAP_M, 0), col_r,
                  col_r * s.uniform("column_taper", 0.7, 1.0)))
    plate = s.uniform("top_plate_radius_m", 0.12, 0.25)
    parts.add(disc((0, h - t - 0.0125 + OVERLAP_M, 0), plate, 0.025))


def _trestle(parts: Parts, s: ParamSampler) -> None:
    h, w, d, t = _top(parts, s, height=(0.70, 0.77), round_top=False, width=(1.2, 2.2),
                      depth_ratio=(0.4, 0.55))
    post_w = s.uniform("post_width_m", 0.06, 0.16)
    post_t = s.uniform("post_thickness_m", 0.04, 0.08)
    foot_h = s.uniform("foot_height_m", 0.05, 0.10)
    cleat_h = s.uniform("cleat_height_m", 0.04, 0.08)
    reach = d / 2 - s.uniform("foot_inset_m", 0.0, 0.08)
    x = w / 2 - s.uniform("trestle_inset_m", 0.12, 0.30) - post_t / 2
    y_top = h - t + OVERLAP_M
    parts.add_pair(
        span_box((x - post_t / 2, -FLOOR_SINK_M, -reach), (x + post_t / 2, foot_h, reach)),
        span_box((x - post_t / 2, h - t - cleat_h, -reach + 0.03), (x + post_t / 2, y_top,
                                                                     reach - 0.03)),
        span_box((x - post_t / 2, foot_h - OVERLAP_M, -post_w / 2),
                 (x + post_t / 2, h - t - cleat_h + OVERLAP_M, post_w / 2)),
    )
    y = s.uniform("stretcher_height_m", 0.15, 0.45)
    sh = s.uniform("stretcher_size_m", 0.05, 0.10)
    parts.add(span_box((-x, y - sh / 2, -0.02), (x, y + sh / 2, 0.02)))


def _coffee(parts: Parts, s: ParamSampler) -> None:
    round_top = s.flag("round_top", 0.35)
    h, w, d, t = _top(parts, s, height=(0.35, 0.48), round_top=round_top,
                      width=(0.6, 1.0) if round_top else (0.8, 1.4), depth_ratio=(0.45, 0.7))
    lw = s.uniform("leg_size_m", 0.035, 0.07)
    round_legs = s.flag("round_legs", 0.5)
    inset = s.uniform("leg_inset_m", 0.0, 0.08)
    if round_top:
        xl = zl = w / 2 / np.sqrt(2) - inset - lw / 2
    else:
        xl, zl = w / 2 - inset - lw / 2, d / 2 - inset - lw / 2
    _legs(parts, s, xl, zl, h - t + OVERLAP_M, round_legs=round_legs, size=lw)
    if s.flag("shelf", 0.5):
        y = s.uniform("shelf_height_m", 0.08, 0.18)
        st = s.uniform("shelf_thickness_m", 0.025, 0.04)
        parts.add(box((2 * xl + lw * 0.8, st, 2 * zl + lw * 0.8), (0, y, 0)))


def _panel(parts: Parts, s: ParamSampler) -> None:
    h, w, d, t = _top(parts, s, height=(0.70, 0.77), round_top=False, width=(0.9, 1.8),
                      depth_ratio=(0.45, 0.7))
    pt = s.uniform("panel_thickness_m", 0.03, 0.06)
    inset = s.uniform("panel_inset_m", 0.0, 0.1)
    depth = d - 2 * s.uniform("panel_depth_inset_m", 0.0, 0.08)
    x = w / 2 - max(inset, CLEARANCE_M) - pt / 2  # a panel flush with the top's side meets it along a line
    parts.add_pair(span_box((x - pt / 2, -FLOOR_SINK_M, -depth / 2),
                            (x + pt / 2, h - t + OVERLAP_M, depth / 2)))
    if s.flag("modesty_panel", 0.6):
        ph = s.uniform("modesty_panel_height_m", 0.25, 0.45)
        z = depth / 2 - s.uniform("modesty_panel_inset_m", 0.02, 0.12)
        parts.add(span_box((-x, h - t - ph, z - 0.0125), (x, h - t + OVERLAP_M, z + 0.0125)))


_BUILDERS = {
    "four_leg_apron": _four_leg_apron,
    "pedestal": _pedestal,
    "trestle": _trestle,
    "coffee": _coffee,
    "panel": _panel,
}
