"""Procedural chairs (metres; +y up, seat front towards -z, back at +z).

Styles: four square legs, four round tapered legs, a tubular sled base, a tubular
cantilever base, an office pedestal on a five-star base with casters, and a bar stool
with a low back. Backs are solid boards, vertical slats or horizontal rails between posts;
arms (armrests on posts) are optional.
"""

from __future__ import annotations

import numpy as np
from manifold3d import Manifold

from jsrte.shapes.params import ParamSampler
from jsrte.shapes.parts import (
    CLEARANCE_M,
    FLOOR_SINK_M,
    OVERLAP_M,
    Parts,
    ball,
    bar,
    box,
    disc,
    placed,
    rod,
    rot_x,
    rot_y,
    rounded_slab,
)

STYLES = ("four_leg_square", "four_leg_round", "sled", "cantilever", "pedestal_star", "bar_stool")
BACK_TYPES = ("solid", "slatted", "ladder")


def generate(rng: np.random.Generator) -> tuple[Parts, str, dict]:
    """Draw one chair: its parts, style name and every parameter drawn."""
    s = ParamSampler(rng)
    style = s.choice("style", STYLES)
    parts = Parts()
    _BUILDERS[style](parts, s)
    return parts, style, s.params


# --- seat and back -----------------------------------------------------------------------------


def _seat(parts: Parts, s: ParamSampler, *, height: tuple[float, float] = (0.42, 0.48),
          width: tuple[float, float] = (0.40, 0.54), thickness: tuple[float, float] = (0.03, 0.08),
          cushion: bool = False) -> tuple[float, float, float, float]:
    """Add the seat slab; returns (seat height, width, depth, thickness) in m (top at height)."""
    h = s.uniform("seat_height_m", *height)
    w = s.uniform("seat_width_m", *width)
    d = s.uniform("seat_depth_m", 0.38, min(0.52, w + 0.06))
    t = s.uniform("seat_thickness_m", *thickness)
    if cushion:
        parts.add(rounded_slab((w, t, d), (0, h - t / 2, 0), 0.3 * t))
    else:
        parts.add(box((w, t, d), (0, h - t / 2, 0)))
    return h, w, d, t


class _BackFrame:
    """The back's local frame: y from the seat's underside, z through the back's mid-plane.

    Local parts are tilted backwards by ``tilt_deg`` about the seat's rear bottom edge.
    """

    def __init__(self, h: float, d: float, t: float, thickness: float, tilt_deg: float) -> None:
        self.origin = np.array([0.0, h - t, d / 2 - thickness / 2])
        self.rotation = rot_x(tilt_deg)
        self.tilt_deg = tilt_deg

    def place(self, solid: Manifold) -> Manifold:
        return placed(solid, self.rotation, self.origin)

    def world(self, local: np.ndarray) -> np.ndarray:
        return self.rotation @ np.asarray(local, np.float64) + self.origin


def _back(parts: Parts, s: ParamSampler, h: float, w: float, d: float, t: float, *,
          round_posts: bool = False, post_size: float | None = None,
          height: tuple[float, float] = (0.32, 0.55), allow_types: tuple[str, ...] = BACK_TYPES,
          ) -> _BackFrame:
    """Add a back (posts plus solid board, vertical slats or horizontal rails)."""
    back_h = s.uniform("back_height_m", *height)
    bt = s.uniform("back_thickness_m", 0.025, 0.045)
    tilt = s.uniform("back_tilt_deg", 0.0, 12.0, digits=2) if s.flag("back_tilted", 0.7) else 0.0
    s.set("back_tilt_deg", tilt)
    kind = s.choice("back_type", allow_types)
    frame = _BackFrame(h, d, t, bt, tilt)
    top = t + back_h
    pw = post_size if post_size is not None else s.uniform("back_post_size_m", 0.03, 0.045)
    has_posts = kind != "solid" or round_posts or s.flag("back_posts", 0.5)
    s.set("back_posts", has_posts)
    xp = w / 2 - pw / 2
    if has_posts:
        if round_posts:
            post = rod((xp, 0.0, 0.0), (xp, top, 0.0), pw / 2)
        else:
            post = box((pw, top, max(pw, bt)), (xp, top / 2, 0.0))
        parts.add_pair(frame.place(post))
    inner = w - 2 * pw if has_posts else w
    if kind == "solid":
        gap = s.uniform("back_gap_m", 0.03, 0.15) if has_posts and s.flag("back_open_below", 0.6) else 0.0
        board_w = inner + 2 * OVERLAP_M if has_posts else w
        bottom = t + gap if gap > 0 else 0.0
        parts.add(frame.place(box((board_w, top - bottom, bt), (0, (top + bottom) / 2, 0))))
    elif kind == "slatted":
        rail_h = s.uniform("top_rail_height_m", 0.05, 0.10)
        n = s.integer("n_slats", 2, 5)
        slat_w = s.uniform("slat_width_m", 0.03, min(0.06, inner / (n + 1)))
        parts.add(frame.place(box((inner + 2 * OVERLAP_M, rail_h, bt), (0, top - rail_h / 2, 0))))
        slat_h = top - rail_h + OVERLAP_M - (t - OVERLAP_M)
        for x in _spread(n, inner):
            slat = frame.place(box((slat_w, slat_h, bt * 0.8), (x, t - OVERLAP_M + slat_h / 2, 0)))
            if x == 0:
                parts.add(slat)
            elif x > 0:
                parts.add_pair(slat)
    else:  # ladder: horizontal rails between the posts
        n = s.integer("n_rails", 2, 4)
        rail_h = s.uniform("rail_height_m", 0.04, 0.07)
        lowest = t + s.uniform("ladder_gap_m", 0.05, 0.12)
        for i in range(n):
            y = top - rail_h / 2 - i * (top - rail_h / 2 - lowest) / max(n - 1, 1)
            parts.add(frame.place(box((inner + 2 * OVERLAP_M, rail_h, bt), (0, y, 0))))
    return frame


def _spread(n: int, span: float) -> list[float]:
    """``n`` x positions spread evenly inside ``span`` m (exactly symmetric about 0)."""
    return [(i - (n - 1) / 2) * span / (n + 1) for i in range(n)]


def _arms(parts: Parts, s: ParamSampler, h: float, w: float, d: float, t: float, frame: _BackFrame,
          *, round_posts: bool = False) -> None:
    """Add armrests on front posts, running back into the back."""
    arm_h = s.uniform("arm_height_m", 0.18, 0.26)
    aw = s.uniform("arm_width_m", 0.045, 0.07)
    at = s.uniform("arm_thickness_m", 0.025, 0.04)
    zf = -d / 2 + s.uniform("arm_post_inset_m", 0.03, 0.09)
    x = w / 2 - aw / 2
    y_top = h + arm_h
    back_z = frame.world([0.0, y_top - frame.origin[1], 0.0])[2]
    z0, z1 = zf - aw / 2 - 0.02, back_z
    inset = CLEARANCE_M if round_posts else 0.0  # else the outer face is tangent to the round back post
    parts.add_pair(box((aw - inset, at, z1 - z0), (x - inset / 2, y_top - at / 2, (z0 + z1) / 2)))
    post_y0, post_y1 = h - OVERLAP_M, y_top - at + OVERLAP_M
    pw = max(0.03, aw * 0.8)
    if round_posts:
        parts.add_pair(rod((x, post_y0, zf), (x, post_y1, zf), pw / 2))
    else:
        parts.add_pair(box((pw, post_y1 - post_y0, pw), (x, (post_y0 + post_y1) / 2, zf)))


# --- bases ---------------------------------------------------------------------------------------


def _four_legs(parts: Parts, s: ParamSampler, h: float, w: float, d: float, t: float,
               *, round_legs: bool) -> None:
    """Four (optionally splayed, tapered) legs, optionally joined by stretchers."""
    lw = s.uniform("leg_size_m", 0.03, 0.055)
    inset = s.uniform("leg_inset_m", 0.0, 0.04)
    splay = s.uniform("leg_splay_m", 0.0, 0.04) if s.flag("legs_splayed", 0.4) else 0.0
    s.set("leg_splay_m", splay)
    taper = s.uniform("leg_taper", 0.6, 1.0) if round_legs else 1.0
    top_y = h - t + OVERLAP_M
    xl, zl = w / 2 - inset - lw / 2, d / 2 - inset - lw / 2

    def leg_point(z_sign: float, y: float) -> np.ndarray:
        frac = 1.0 - (y + FLOOR_SINK_M) / (top_y + FLOOR_SINK_M)
        return np.array([xl + splay * frac, y, z_sign * (zl + splay * frac)])

    for z_sign in (-1.0, 1.0):
        p0, p1 = leg_point(z_sign, -FLOOR_SINK_M), leg_point(z_sign, top_y)
        if round_legs:
            parts.add_pair(rod(p0, p1, max(0.015, lw / 2 * taper), lw / 2))
        else:
            parts.add_pair(bar(p0, p1, lw))
    if s.flag("stretchers", 0.5):
        y = s.uniform("stretcher_height_m", 0.10, 0.25)
        sr = 0.015
        a, b = leg_point(-1.0, y), leg_point(1.0, y)
        parts.add_pair(rod(a, b, sr) if round_legs else bar(a, b, 2 * sr))
        if s.flag("front_stretcher", 0.5):
            left = a * np.array([-1.0, 1.0, 1.0])
            parts.add(rod(left, a, sr) if round_legs else bar(left, a, 2 * sr))


def _four_leg(parts: Parts, s: ParamSampler, *, round_legs: bool) -> None:
    h, w, d, t = _seat(parts, s)
    _four_legs(parts, s, h, w, d, t, round_legs=round_legs)
    frame = _back(parts, s, h, w, d, t, round_posts=round_legs)
    if s.flag("arms", 0.35):
        _arms(parts, s, h, w, d, t, frame, round_posts=round_legs)


def _four_leg_square(parts: Parts, s: ParamSampler) -> None:
    _four_leg(parts, s, round_legs=False)


def _four_leg_round(parts: Parts, s: ParamSampler) -> None:
    _four_leg(parts, s, round_legs=True)


def _tube_base(parts: Parts, s: ParamSampler, *, cantilever: bool) -> None:
    """Chrome-tube bases: a sled (runner plus front and rear uprights per side) or a cantilever
    (floor U, front uprights only, seat carried by rails from the front)."""
    h, w, d, t = _seat(parts, s, thickness=(0.03, 0.06))
    r = s.uniform("tube_radius_m", 0.015, 0.02)
    x = w / 2 - r
    y_floor = r - 0.004
    y_seat = h - t - r + OVERLAP_M
    zf = -d / 2 + r + s.uniform("front_upright_inset_m", 0.0, 0.05)
    zb = d / 2 - r - s.uniform("rear_upright_inset_m", 0.0, 0.05)
    if cantilever:
        z_floor_front = zf - s.uniform("runner_overhang_m", 0.0, 0.06)
        z_floor_back = d / 2 - s.uniform("runner_back_inset_m", 0.05, 0.15)
        corners = [(x, y_floor, z_floor_back), (x, y_floor, z_floor_front), (x, y_seat, zf),
                   (x, y_seat, zb)]
        parts.add(rod((-x, y_floor, z_floor_back), (x, y_floor, z_floor_back), r))
    else:
        corners = [(x, y_seat, zf), (x, y_floor, zf - 0.03), (x, y_floor, zb + 0.03), (x, y_seat, zb)]
        if s.flag("floor_crossbar", 0.5):
            parts.add(rod((-x, y_floor, zb + 0.03), (x, y_floor, zb + 0.03), r))
    for a, b in zip(corners[:-1], corners[1:], strict=True):
        parts.add_pair(rod(a, b, r))
    for c in corners:
        parts.add_pair(ball(c, r))
    frame = _back(parts, s, h, w, d, t, round_posts=True, post_size=2 * r,
                  allow_types=("solid", "ladder"))
    if s.flag("arms", 0.3):
        _arms(parts, s, h, w, d, t, frame, round_posts=True)


def _sled(parts: Parts, s: ParamSampler) -> None:
    _tube_base(parts, s, cantilever=False)


def _cantilever(parts: Parts, s: ParamSampler) -> None:
    _tube_base(parts, s, cantilever=True)


def _pedestal_star(parts: Parts, s: ParamSampler) -> None:
    """An office chair: cushion seat on a gas column over a five-star base with casters."""
    h, w, d, t = _seat(parts, s, height=(0.44, 0.52), width=(0.44, 0.52), thickness=(0.06, 0.10),
                       cushion=True)
    radius = s.uniform("star_radius_m", 0.27, 0.34)
    cr = s.uniform("caster_radius_m", 0.025, 0.032)
    arm_w = s.uniform("star_arm_width_m", 0.035, 0.05)
    arm_t = s.uniform("star_arm_thickness_m", 0.03, 0.045)
    hub_r = s.uniform("hub_radius_m", 0.04, 0.055)
    col_r = s.uniform("column_radius_m", 0.022, 0.032)
    y_end = 2 * cr - 0.008 + arm_t / 2
    y_hub = y_end + s.uniform("star_rise_m", 0.0, 0.04)
    hub_h = s.uniform("hub_height_m", 0.05, 0.08)
    parts.add(placed(Manifold.cylinder(hub_h, hub_r, hub_r, 24, True), rot_x(-90.0),
                     (0, y_hub, 0)))
    for k in range(3):  # arm k=0 points to the front (-z); arms 1, 2 are mirrored to 4, 3
        ang = 72.0 * k
        direction = rot_y(ang) @ np.array([0.0, 0.0, -1.0])
        end = direction * radius
        arm = bar((0.0, y_hub, 0.0), (end[0], y_end, end[2]), arm_w, arm_t)
        caster = ball((end[0], cr - 0.004, end[2]), cr)
        stem = rod((end[0], cr, end[2]), (end[0], y_end, end[2]), 0.012)
        if k == 0:
            parts.add(arm, caster, stem)
        else:
            parts.add_pair(arm, caster, stem)
    parts.add(rod((0, y_hub, 0), (0, h - t + OVERLAP_M, 0), col_r))
    # seat plate under the cushion, then a spine from it up behind the back
    parts.add(box((0.22, 0.04, 0.24), (0, h - t - 0.02 + OVERLAP_M, 0.02)))
    back_h = s.uniform("back_height_m", 0.40, 0.62)
    bt = s.uniform("back_thickness_m", 0.04, 0.08)
    gap = s.uniform("back_gap_m", 0.04, 0.12)
    tilt = s.uniform("back_tilt_deg", 4.0, 14.0, digits=2)
    spine_w = s.uniform("spine_width_m", 0.04, 0.07)
    bz = d / 2 + bt / 2 + 0.01
    rot = rot_x(tilt)
    origin = np.array([0.0, h + gap, bz])
    bw = w * s.uniform("back_width_ratio", 0.85, 1.0)
    parts.add(placed(rounded_slab((bw, back_h, bt), (0, back_h / 2, 0), 0.3 * bt), rot, origin))
    spine_top = rot @ np.array([0.0, back_h * 0.4, bt / 2]) + origin
    spine_bottom = np.array([0.0, h - t - 0.02, 0.10])
    corner = np.array([0.0, spine_bottom[1], spine_top[2] + 0.01])
    parts.add(bar(spine_bottom - [0, 0, spine_w / 2], corner + [0, 0, spine_w / 2], spine_w, 0.03))
    parts.add(bar(corner - [0, 0.015, 0], spine_top, spine_w, 0.03))
    if s.flag("arms", 0.5):
        arm_h = s.uniform("arm_height_m", 0.18, 0.26)
        aw = s.uniform("arm_width_m", 0.05, 0.08)
        ad = s.uniform("arm_length_m", 0.22, 0.30)
        zc = s.uniform("arm_z_m", -0.02, 0.06)
        x_post = w / 2 - 0.005
        parts.add_pair(box((aw, 0.03, ad), (w / 2 + aw / 2 - 0.02, h + arm_h - 0.015, zc)))
        parts.add_pair(box((0.03, arm_h + t, 0.05), (x_post, h - t + (arm_h + t) / 2, zc)))


def _bar_stool(parts: Parts, s: ParamSampler) -> None:
    """A tall stool: splayed legs with a footrest ring and a low back."""
    h = s.uniform("seat_height_m", 0.62, 0.78)
    round_seat = s.flag("round_seat", 0.5)
    w = s.uniform("seat_width_m", 0.36, 0.44)
    t = s.uniform("seat_thickness_m", 0.03, 0.06)
    d = w
    if round_seat:
        parts.add(disc((0, h - t / 2, 0), w / 2, t))
    else:
        parts.add(box((w, t, d), (0, h - t / 2, 0)))
    round_legs = s.flag("round_legs", 0.5)
    lw = s.uniform("leg_size_m", 0.03, 0.045)
    splay = s.uniform("leg_splay_m", 0.02, 0.08)
    a = w / 2 * (0.6 if round_seat else 0.75)
    top_y = h - t + OVERLAP_M

    def leg_point(z_sign: float, y: float) -> np.ndarray:
        frac = 1.0 - (y + FLOOR_SINK_M) / (top_y + FLOOR_SINK_M)
        return np.array([a + splay * frac, y, z_sign * (a + splay * frac)])

    for z_sign in (-1.0, 1.0):
        p0, p1 = leg_point(z_sign, -FLOOR_SINK_M), leg_point(z_sign, top_y)
        parts.add_pair(rod(p0, p1, lw / 2) if round_legs else bar(p0, p1, lw))
    y = s.uniform("footrest_height_m", 0.22, 0.34)
    fr = 0.015
    f, b = leg_point(-1.0, y), leg_point(1.0, y)
    mirror = np.array([-1.0, 1.0, 1.0])
    parts.add_pair(rod(f, b, fr))
    parts.add(rod(f * mirror, f, fr), rod(b * mirror, b, fr))
    # low back: two posts and a rail, tilted slightly
    back_h = s.uniform("back_height_m", 0.14, 0.30)
    rail_h = s.uniform("back_rail_height_m", 0.05, min(0.12, back_h - 0.03))
    bt = s.uniform("back_thickness_m", 0.025, 0.04)
    tilt = s.uniform("back_tilt_deg", 0.0, 12.0, digits=2)
    xp = w / 2 * (0.55 if round_seat else 0.85)
    if round_seat:
        zb = float(np.sqrt((w / 2) ** 2 - (xp + 0.015) ** 2)) - 0.015 - bt / 2
    else:
        zb = d / 2 - bt / 2
    origin = np.array([0.0, h - t, zb])
    rot = rot_x(tilt)
    top = t + back_h
    post = rod((xp, 0.0, 0.0), (xp, top - rail_h / 2, 0.0), 0.015) if round_legs else \
        box((0.03, top - rail_h / 2, 0.03), (xp, (top - rail_h / 2) / 2, 0.0))
    parts.add_pair(placed(post, rot, origin))
    parts.add(placed(box((2 * xp + 0.06, rail_h, bt), (0, top - rail_h / 2, 0)), rot, origin))


_BUILDERS = {
    "four_leg_square": _four_leg_square,
    "four_leg_round": _four_leg_round,
    "sled": _sled,
    "cantilever": _cantilever,
    "pedestal_star": _pedestal_star,
    "bar_stool": _bar_stool,
}
