"""Whole scenes: every object standing on the floor of a scan, each with its class and its fit.

The scan is segmented once (``jsrte.fit.query.scan_candidates``: floor, walls, clusters). With
the class unknown, every cluster is cut at its weak necks (:data:`SCENE_SEGMENT`), each whole
staying a candidate beside its parts: two objects side by side and one object with a narrow
place look alike before a fit. Then:

0. every candidate that may be an object and is an upright cuboid seen solid is a box
   (``jsrte.scans.boxes``): clutter no model covers, recorded with its cuboid and never fitted;
1. every other candidate that may be an object (not too small, too flat or too big) is fitted
   quickly by each model (``jsrte.fit.screen.choose_class``: the same scale-free screen score
   that picks the class of a single object); with one model, only the candidates of a split;
2. each split is judged by those fits (:func:`judge_splits`): the whole is one object where its
   fit explains its points as well as its parts' fits explain theirs, and the points of every
   part nearly as well as that part's own fit, and no part is a box; else its parts are;
3. every object left gets the full fit with its class and the preset's settings; where the
   screen leaves two classes close, their full fits decide (``jsrte.fit.classes``); a full fit
   that lies on almost none of its points is fitted again by ``fast-gn``
   (``jsrte.fit.scene_refits``);
4. a fit that explains too little of its points, ends outside its class's sizes, or that its
   points barely cover (a table: its top) is no object (``unexplained``); one that ends outside
   its class's sizes is fitted with the class the screen ranked next whose sizes hold it
   (:func:`fit_another_class`), kept where that fit holds; a table whose top the scan did not
   see, and a shape its points barely cover, are fitted in full with every other class the
   screen left close, and the one whose fit explains its points far better than the rejected
   one's is kept where it holds (:func:`fit_other_classes_in_full`); a table no other class
   explains is fitted again as a table by ``fast-gn``, kept where that fit holds and
   is flagged ok (:func:`search_again`);
5. of two objects whose fitted shapes share much of their volume (two fits of one object, from
   two of its pieces), the one whose fit lies on fewer of the points of both is no object
   (:func:`drop_second_fits`); a table found by that second search gives way to any object
   found before it;
6. an object whose fitted surface the scan's cameras saw through on much of it is no object
   (:func:`drop_seen_through`);
7. last, a found object whose fitted surface the cameras saw through on some of it is fitted
   again by ``fast-gn``, the new fit kept where they saw through far less of it and it is
   still found (:func:`refit_seen_through`); then every found object whose points lie loosely
   on its fit is flagged doubtful (:func:`flag_loose_fits`).

A candidate whose fit fails (too few points, a degenerate cluster) is recorded as failed with
the reason and the others go on; candidates the segmentation rejected are listed as skipped with
their point counts, those the judgement set aside as covered. ``jsrte.fit.scene_outputs``
writes the files.
"""

from __future__ import annotations

import time
from collections.abc import Callable, Iterator
from concurrent.futures import ThreadPoolExecutor
from contextlib import contextmanager
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

import numpy as np

from jsrte.errors import JsrteError
from jsrte.fit.query import SdfQuery
from jsrte.fit.scene_checks import (
    FOUND_SHARE,
    PART_EXPLAINED,
    box_centre,
    drop_second_fits,
    drop_seen_through,
    flag_loose_fits,
    flag_scene_object,
    mark_unexplained,
    points_on_fit,
)
from jsrte.fit.scene_refits import (
    ANOTHER_CLASS_AFTER,
    IN_FULL_AFTER,
    SEARCHED_AGAIN_AFTER,
    fit_another_class,
    fit_other_classes_in_full,
    refit_escaped,
    refit_seen_through,
    search_again,
    seen_through_in_part,
)
from jsrte.fit.screen import CLASS_FIT, SCREEN_FIT, Choice, Screened, ScreenSettings
from jsrte.options import FitOptions
from jsrte.presets import SCENE_PRESET
from jsrte.result import FitResult
from jsrte.scans.boxes import BoxEvidence, BoxSettings, candidate_boxes
from jsrte.scans.segment import SegmentSettings
from jsrte.scans.veil import VeilSettings
from jsrte.scans.views import CameraViews


@dataclass
class SceneObject:
    """One candidate object of a scene and what became of it.

    Attributes
    ----------
    index : its number in the scene (objects/NN/), in the order fitted
    candidate : its position in the segmentation's candidates
    points : (m, 3) float64 its scan points (scan units)
    status : "ok" (fitted: an object of its class), "unexplained" (fitted, but its fit lies on
        fewer than :data:`FOUND_SHARE` of its points, or its size is none of its class's:
        no model covers it), "box" (a box: not fitted, its cuboid in ``box``) or "failed"
    reason : why it failed or is unexplained ("" when fitted)
    model : the name of the model fitted (the class), None when it failed before the choice
    class_choice : every class's screen score and the margin (None with one model)
    result : the fit (None when it failed)
    choice : its quick fits by every model (``jsrte.fit.screen.Choice``; None: not screened,
        a text: why it could not be)
    unexplained_by : which check left it unexplained: "share", "size", "coverage", "top",
        "second fit", "seen through", "piece" (a piece of a whole fitted in its stead,
        :func:`_fit_split_wholes`) or "parts" (a whole fitted as its parts, as its fit left one
        over, :func:`_fit_parts_left_over`; "" when it is not)
    box : the evidence that it is a box, its cuboid in it (None: not a box)
    leftover_of : the found object whose fit left its points unexplained (a part of its candidate,
        :func:`_fit_parts_left_over`, or with ``leftovers`` a cluster of its points,
        :func:`_fit_leftovers`; None: judged an object itself)
    part_of : the object, a whole of which this is a part, whose fit a check of
        :data:`FIRST_PARTS_AFTER` dropped (:func:`_fit_parts_of_dropped`) or left a part over
        (:func:`_fit_parts_left_over`; None: judged an object itself)
    views : the scan's readings by camera, to find where the cameras saw through its fit (None:
        the scan does not say which camera saw each point)
    """

    index: int
    candidate: int
    points: np.ndarray = field(repr=False)
    status: str = "ok"
    reason: str = ""
    model: str | None = None
    class_choice: dict[str, Any] | None = None
    result: FitResult | None = None
    choice: Choice | str | None = field(default=None, repr=False)
    unexplained_by: str = ""
    box: BoxEvidence | None = field(default=None, repr=False)
    leftover_of: int | None = None
    part_of: int | None = None
    views: CameraViews | None = field(default=None, repr=False)

    @property
    def centre(self) -> list[float]:
        """The centre of its points' bounding box (3,), scan units."""
        return ((self.points.min(0) + self.points.max(0)) / 2.0).tolist()

    def to_json(self) -> dict[str, Any]:
        """scene.json's record of the object."""
        entry: dict[str, Any] = {"index": self.index, "folder": f"objects/{self.index:02d}", "status": self.status,
                                 "candidate": self.candidate, "points": len(self.points),
                                 "candidate_centre": [round(v, 5) for v in self.centre], "class": self.model}
        if self.box is not None:
            entry.update({"folder": None, "class": BOX_CLASS, "cuboid": self.box.cuboid.to_json(),
                          "box_evidence": self.box.to_json()})
        if self.class_choice is not None:
            entry["class_scores"] = self.class_choice.get("scores")
            entry["class_margin"] = self.class_choice.get("margin")
        if self.reason:
            entry["reason"] = self.reason
        if self.leftover_of is not None:
            entry["leftover_of"] = self.leftover_of
        if self.part_of is not None:
            entry["part_of"] = self.part_of
        r = self.result
        if r is not None:
            mesh = r.mesh
            entry.update(transform=r.transform.to_dict(),
                         latent=None if r.latent is None else np.asarray(r.latent, float).round(6).tolist(),
                         fitted_centre=None if mesh is None else box_centre(np.asarray(mesh.vertices)),
                         flag=r.flag, quality=json_ready(r.quality), loss=json_ready({"loss": r.loss})["loss"],
                         time_s=r.timing.get("total"))
        return entry


@dataclass
class SceneResult:
    """Every object of a scan, fitted.

    Attributes
    ----------
    objects : the candidates fitted (or failed), best class rank first
    skipped : the candidates the segmentation rejected: position, points, reason
    segmentation : the segmentation's record (walls, removed points, candidates)
    scan_points : (n, 3) float64 the scan's points (scan units), for figures
    up : (3,) the up axis (floor normal)
    floor_offset : the floor plane is {x : up·x = floor_offset}; None without a floor
    options : the fit options as recorded
    models : the names of the models the classes were chosen among
    covered : the candidates judged no object of their own (pieces of a whole, or wholes of
        several objects): position, points, reason
    timing : wall seconds of each phase (:data:`PHASES`) and in all
    """

    objects: list[SceneObject]
    skipped: list[dict[str, Any]]
    segmentation: dict[str, Any]
    scan_points: np.ndarray = field(repr=False)
    up: np.ndarray | None = None
    floor_offset: float | None = None
    options: dict[str, Any] = field(default_factory=dict)
    models: list[str] = field(default_factory=list)
    covered: list[dict[str, Any]] = field(default_factory=list)
    timing: dict[str, float] = field(default_factory=dict)

    @property
    def fitted(self) -> list[SceneObject]:
        """The objects whose fit succeeded (unexplained ones included: their files are written)."""
        return [o for o in self.objects if o.result is not None]

    @property
    def found(self) -> list[SceneObject]:
        """The objects found: fitted, and explained by their class's fit."""
        return [o for o in self.objects if o.status == "ok"]

    @property
    def boxes(self) -> list[SceneObject]:
        """The objects found to be boxes (not fitted)."""
        return [o for o in self.objects if o.status == BOX_CLASS]

    def to_json(self) -> dict[str, Any]:
        """scene.json: the objects, the skipped candidates, walls, floor and options."""
        seg = self.segmentation
        return {"format": "jsrte-scene", "models": self.models, "options": self.options,
                "floor": {"up": None if self.up is None else np.asarray(self.up, float).tolist(),
                          "offset": self.floor_offset},
                "walls": seg.get("walls", []), "removed": seg.get("removed", {}),
                "objects": [o.to_json() for o in self.objects], "skipped": self.skipped, "covered": self.covered,
                "counts": {"fitted": len(self.found), "boxes": len(self.boxes),
                           "unexplained": len(self.fitted) - len(self.found),
                           "failed": len(self.objects) - len(self.fitted) - len(self.boxes),
                           "skipped": len(self.skipped)},
                "timing_s": self.timing}


SCENE_SEGMENT = SegmentSettings(cut_max_without_class=0.008, join_keeps_parts_without_class=True,
                                join_apart_m=0.4, floating_top_m=0.6, piece_share=0.9)
"""The segmentation of a scene whose class is unknown: without a class shape to say where to cut,
every neck of normalized cut 0.008 or less is cut (the whole staying a candidate beside its
parts), and fits of the whole and of its parts decide (:func:`judge_splits`). On the tuning
rooms (100-129 of seed 0) every cut between two objects touching each other scored 0.0074 or
less; cuts within one object ran from 0.0007 to 0.02. Cuts along three eigenvectors
(``cut_vectors=3``) give more objects a candidate of their own but were not better once fitted
(docs/clutter.md, Limits). Two clusters within joining reach that could each be an object (two
tables side by side, a chair beside a bed) stay the parts of their join
(``join_keeps_parts_without_class``), judged as a split's; so do two up to 40 cm apart
(``join_apart_m``): a bed whose middle the scan did not see. Most joins that far hold two
objects: the judgement keeps their parts, and a whole judged one object whose fit is dropped
gives way to its parts (:func:`_fit_parts_of_dropped`). A slab whose underside floats 0.6 m or
more above the floor (``floating_top_m``) is as tall as its top, not too flat: a table's top seen
without the legs or pedestal it hides from cameras above; its full fits are held to the floor
(:data:`FLOATING_TOP_FLOOR_CONTACT`). A split's part too big only for a scrap of a neighbour the
cut gave it far away is its largest connected piece (``piece_share``)."""

FLOATING_TOP_FLOOR_CONTACT = 0.3
"""The floor contact (``FitOptions.floor_contact``) of the full fits of a candidate that floats
(``Candidate.floats``): nothing in the points of a top seen alone says how far down its shape
reaches, and a top fitted freely ends with its legs in the air or beside it. The weight of the
``fast-scales-floor`` preset (docs/presets.md, "Tables held to the floor"); other candidates are
not held (on the reported rooms, holding every table found two fewer)."""


SCENE_FIT_VEIL: VeilSettings | None = None
"""With settings, every fit of a scene, quick or full, leaves the sensor's mixed pixels
(``jsrte.scans.veil``, where the scan says which camera saw each point) out of its candidate's
points, not out of the segmentation (``PrepareSettings.fit_veil``). Off: on the tuning rooms it
found one object fewer with two false detections fewer, and on the reported rooms 0-9 it lost
class accuracy and F@5% (docs/clutter.md, "Whole scenes", step 3)."""


SCENE_SCREEN = ScreenSettings(fit=replace(SCREEN_FIT, init_scale="both", code_screen_samples=50),
                              class_fit=replace(CLASS_FIT, init_scale="both", code_screen_samples=50),
                              final_size_margin=None, explained_floor=0.03, final_far_code=1.1)
"""The quick fits of a scene's candidates: every yaw starts at the height's scale and, where it
differs by more than 10%, at the bounding sphere's too (``FitSettings.init_scale`` "both"), the
forward-pass screen keeping the best four of all. The training codes a quick fit restarts from
are scored on 50 samples, as ``fast-gn`` scores them, not 400 (``code_screen_samples``): that
scoring was two thirds of a quick fit. On the tuning rooms 100-119 of seed 0 the same objects
are found with the same classes (one bed's F@5% 0.98 -> 0.94, one sofa's flag ok -> doubtful)
in 19 s of quick fits a scene instead of 36. Beds, sofas and tables vary in proportions far
more than chairs; a bed's quick fit started from its height alone can end far off, and the
judgement then cuts the bed into pieces. A scene weighs each fit's size after the class is
chosen instead (``jsrte.fit.scene_checks.SIZE_MARGIN``). A part's own fit counts at least 0.03 of its radius from
its points when a whole is judged against it (``explained_floor``): on the tuning rooms (100-169
of seed 0, 282 pieces of furniture; ``benchmarks/bench_split_judgement.py``) 217 kept a candidate
of their own without it, 222 with 0.02, 225 with 0.03 (the most), and 0.035-0.04 kept two to five
more wholes of two objects. Where both classes fitted in full to settle a close screen needed a
code beyond 1.1 times their training codes' median distance (``final_far_code``, the scene's
flag bound on a code: ``jsrte.fit.scene_checks.SCENE_CODE_RATIO_MAX``), neither model knows the shape, and the
third close class is fitted too (a sofa whose screen ranked bed and table first)."""


BOX_CLASS = "box"
"""The class (and status) of a scene object found to be a box (``jsrte.scans.boxes``)."""


SCENE_BOXES = BoxSettings()
"""What makes a scene's candidate a box (``jsrte.scans.boxes.BoxSettings``)."""


SCENE_FLOAT32_RETRY = False
"""A scene's doubtful fits are kept as they are, not fitted again in float32
(``FitSettings.float32_retry``): on the tuning rooms 100-107 the retry refitted 17 of the 39
full fits (clutter leaves many doubtful), each a float32 fit more (about twice a bfloat16 fit's
time), and moved class choices both ways: recall 0.77 -> 0.74, precision 0.73 -> 0.74, mean F@5%
of the found objects 0.79 -> 0.82 (docs/clutter.md)."""



def fit_scene(path: str | Path, *, model: object = "auto", options: FitOptions | None = None,
              screen: ScreenSettings = SCENE_SCREEN, progress: bool = False, workers: int = 1,
              boxes: BoxSettings | None = SCENE_BOXES, leftovers: bool = False, **changes: object) -> SceneResult:
    """Fit every object standing on the floor of the scan at ``path``.

    Parameters
    ----------
    path : a scan (PLY/PCD/XYZ, metres, floor found or ``up`` given)
    model : the models the class is chosen among (as ``jsrte.fit.fit``: "auto" for every
        shipped model, "chair,table", a list, or one model: then no class is chosen)
    options : how to fit (``FitOptions``, default preset :data:`jsrte.presets.SCENE_PRESET`; ``at``
        is refused: a scene fits every object)
    screen : how the class of each object is screened and each split judged
    progress : show a progress bar over the quick fits (candidates screened) and one over the
        full fits (objects)
    workers : objects screened and fitted at once, each in a thread of its own with one PyTorch
        thread (the fits' PyTorch and NumPy work runs outside Python's interpreter lock); 1: one
        after the other, with PyTorch's threads as they are set
    boxes : what makes a candidate a box (None: nothing is, every candidate is fitted)
    leftovers : also fit, as objects of their own, the points that the found objects' fits leave
        unexplained (:func:`_fit_leftovers`): an object segmented with another (a chair pushed
        against a bed) is found so
    changes : options by name, applied over ``options``

    Raises ``JsrteError`` when the scan holds no object (saying what segmentation removed).
    """
    from jsrte.fit import _array, load_models
    from jsrte.fit.query import class_shape, scan_candidates
    from jsrte.timing import stage

    options = (options or FitOptions(preset=SCENE_PRESET)).changed(**changes)
    if options.float32_retry is None:
        options = options.changed(float32_retry=SCENE_FLOAT32_RETRY)
    if options.at is not None:
        raise JsrteError("--scene fits every object; --at picks one (give one or the other)", path)
    timing: dict[str, float] = {}
    started = time.perf_counter()
    with stage("load"), _timed(timing, "segmentation"):
        models = load_models(model, options.device)
        settings = options.settings()
        shape = class_shape(next(iter(models.values()))) if len(models) == 1 else None
        cands = scan_candidates(path, rng=np.random.default_rng(options.seed), up=_array(options.up),
                                viewpoints=_array(options.viewpoints), settings=settings.scan_sdf,
                                units_check=options.units_check, shape=shape,
                                segment=SegmentSettings() if shape is not None else SCENE_SEGMENT,
                                fit_veil=SCENE_FIT_VEIL)
        found_boxes = {} if boxes is None else candidate_boxes(cands, cands.possible(), boxes)
        views = CameraViews.of_scan(cands.segmented.cloud.points, cands.segmented.cloud.view,
                                    cands.segmented.viewpoints)
    screen = screen.held_to_sizes(settings.fit.size_margin).in_arithmetic(options.dtype).searched_as(settings.fit)
    segmented = cands.segmented
    seg = cands.segmentation
    cloud_points = np.asarray(segmented.cloud.points, float)
    to_screen = _to_screen(cands, several=len(models) > 1, boxes=set(found_boxes))
    with _timed(timing, "quick fits"):
        screened = dict(_in_threads(lambda k: _screen_candidate(k, cands, models, options, screen), to_screen,
                                    workers, bar=f"quick fits of {len(to_screen)} candidates by {len(models)} "
                                    "model(s)" if progress and to_screen else None, unit="candidate"))
        covered = judge_splits(seg.candidates, screened, models, screen, options.seed, boxes=set(found_boxes))
    found = [k for k in cands.possible() if k not in covered]
    objects = [SceneObject(number, k, cloud_points[segmented.index[seg.candidates[k].index]],
                           choice=screened.get(k), box=found_boxes.get(k),
                           status=BOX_CLASS if k in found_boxes else "ok", views=views)
               for number, k in enumerate(found)]
    to_fit = [o for o in objects if o.box is None]
    with _timed(timing, "full fits"):
        _in_threads(lambda obj: _fit_object(obj, cands, models, options, screen), to_fit, workers,
                    bar=f"fitting {len(to_fit)} objects" if progress and to_fit else None, unit="object")
    with _timed(timing, "checks"):
        searched = _check_objects(objects, models, options, workers, screen)
        drop_second_fits([o for o in objects if not any(o is f for f in searched)], models, options.seed)
        drop_second_fits(objects, models, options.seed, newcomers=searched)
        drop_seen_through(objects)
        objects += _fit_parts_of_dropped(objects, cands, screened, found_boxes, models, options, screen, workers,
                                         views)
        turned_down: dict[int, str] = {}
        objects += _fit_split_wholes(objects, cands, screened, covered, models, options, screen, views, turned_down)
        objects += _fit_parts_left_over(objects, cands, screened, found_boxes, models, options, screen, workers, views)
        _in_threads(lambda obj: refit_seen_through(obj, models, options), seen_through_in_part(objects, options),
                    workers)
    if leftovers:
        with _timed(timing, "leftovers"):
            extra = _fit_leftovers(objects, cands, models, options, screen, boxes, workers, views)
            drop_second_fits(objects + extra, models, options.seed, newcomers=extra)
            drop_seen_through(extra)
            objects += extra
    flag_loose_fits(objects)
    timing["total"] = round(time.perf_counter() - started, 2)
    skipped = [{"candidate": k, "points": len(c.index), "reason": c.rejected}
               for k, c in enumerate(seg.candidates) if c.rejected]
    floor = segmented.floor
    return SceneResult(objects, skipped, seg.to_json(), cloud_points, up=np.asarray(segmented.up, float),
                       floor_offset=None if floor is None else float(floor.offset),
                       options=options.record(), models=list(models),
                       covered=_covered_json(seg.candidates, covered, turned_down), timing=timing)


PHASES = ("segmentation", "quick fits", "full fits", "checks", "leftovers")
"""The phases of :func:`fit_scene` whose wall seconds ``SceneResult.timing`` (scene.json's
``timing_s``) records: models loaded and the scan segmented; every candidate fitted quickly by
every model and the splits judged; the full fits (contending classes and refits included); the
coverage, size and second-fit checks with the other-class fits they call for and the fits of
the parts of dropped wholes (:func:`_fit_parts_of_dropped`), of the split wholes fitted in full
(:func:`_fit_split_wholes`) and the refits of what the cameras saw through
(:func:`refit_seen_through`); the leftovers' clustering, quick fits, full fits and checks (:func:`_fit_leftovers`)."""


@contextmanager
def _timed(timing: dict[str, float], phase: str) -> Iterator[None]:
    """Add the block's wall seconds to ``timing[phase]``."""
    started = time.perf_counter()
    try:
        yield
    finally:
        timing[phase] = round(timing.get(phase, 0.0) + time.perf_counter() - started, 2)


def _to_screen(cands: object, several: bool, boxes: set[int] = frozenset()) -> list[int]:
    """The candidates to fit quickly: with ``several`` models every one (its class is chosen so)
    but the ``boxes`` outside any split; with one, those of a split (a whole and its parts are
    judged against each other)."""
    candidates = cands.segmentation.candidates

    def in_split(k: int) -> bool:
        return bool(candidates[k].parts) or candidates[k].parent is not None

    return [k for k in cands.possible() if in_split(k) or (several and k not in boxes)]


def _screen_candidate(k: int, cands: object, models: dict, options: FitOptions,
                      screen: ScreenSettings) -> tuple[int, Choice | str]:
    """Candidate ``k``'s query screened by every model (``jsrte.fit.screen.choose_class``), or
    why it could not be."""
    from jsrte.fit.screen import choose_class

    try:
        return k, choose_class(_query(cands, k, options), models, settings=screen, seed=options.seed)
    except JsrteError as exc:
        return k, str(exc)


def _query(cands: object, k: int, options: FitOptions) -> SdfQuery:
    """The SDF query of candidate ``k``, its record saying the scene chose it."""
    query = cands.query(k, rng=np.random.default_rng(options.seed))
    query.info["segmentation"] |= {"chosen": k, "chosen_by": "scene"}
    return query


def judge_splits(candidates: list, screened: dict[int, Choice | str], models: dict, settings: ScreenSettings,
                 seed: int, boxes: set[int] = frozenset(),
                 ratio: Callable[[int, int], float] | None = None) -> set[int]:
    """The candidates that are not objects of their own, each split judged by the quick fits of
    its whole and its parts (``jsrte.fit.screen.split_or_whole``): a candidate scores its best
    class's screen score, and the whole's best fit must lie at most ``whole_explains`` times
    as far from the points of every part some model explains well (a screen score of at most
    :data:`PART_EXPLAINED`, and from its best part, maybe a part of a part; a part judged to hold
    several objects counts as those of them some model explains well, or as itself where none
    is) as that part's own best fit (``jsrte.fit.screen.explained_ratio``, each fit by its own model). A
    single object's split asks it of the best part only; a scene keeps every part, and a table
    fitted to a table and the chair beside it explains the table's points well but not the
    chair's. A join of clusters farther apart than the segmentation's join (its summary's
    ``joined_apart``) asks it of every part, explained well or not: a chair barely seen 30 cm from
    a sofa is an object of its own unless the sofa's fit lies on it. A whole of which a part
    (or a part's part) is one of ``boxes`` holds several objects. ``screened``: candidate
    position -> its screens (or why it has none: a whole that has none, or has a part with none,
    is not judged, its parts stand). ``ratio(whole, part)``: that ratio where it is known
    already (None: from the best screens' fits)."""
    from jsrte.fit.screen import explained_ratio, split_or_whole

    def best(k: int) -> Screened:
        return min(screened[k].screened, key=lambda s: s.score)

    def holds_box(k: int) -> bool:
        return any(p in boxes or holds_box(p) for p in candidates[k].parts)

    def explains(whole: int, best_part: int, objects: list[list[int]]) -> float:
        if holds_box(whole):
            return float("inf")
        parts = {best_part}
        every_part = candidates[whole].summary.get("joined_apart", False)
        for part, stands_for in zip(candidates[whole].parts, objects, strict=True):
            if every_part:
                parts.update(stands_for)
                continue
            explained = [o for o in stands_for if best(o).score <= PART_EXPLAINED]
            parts.update(explained or ([part] if best(part).score <= PART_EXPLAINED else []))
        if ratio is not None:
            return max(ratio(whole, p) for p in parts)
        by_whole = best(whole)
        return max(explained_ratio(models[by_whole.model], by_whole, best(p), settings, seed,
                                   part_model=models[best(p).model]) for p in parts)

    scores = {k: best(k).score for k, choice in screened.items() if isinstance(choice, Choice)}
    unjudged = {k for k, c in enumerate(candidates) if c.parts and not c.rejected and k not in scores}
    return split_or_whole(candidates, scores, explains, settings) | unjudged


def _covered_json(candidates: list, covered: set[int], fitted_whole: dict[int, str] | None = None
                  ) -> list[dict[str, Any]]:
    """scene.json's record of the candidates judged no object of their own; ``fitted_whole``:
    candidate -> why its fit in full, made by :func:`_fit_split_wholes`, was turned down."""
    out = []
    for k in sorted(covered):
        c = candidates[k]
        reason = "holds several objects (fitted as its parts)" if c.parts else f"a piece of candidate {c.parent}"
        entry = {"candidate": k, "points": len(c.index), "reason": reason}
        if fitted_whole and k in fitted_whole:
            entry["fitted_whole"] = fitted_whole[k]
        out.append(entry)
    return out


def _in_threads(function: Callable[[Any], Any], items: list, workers: int, bar: str | None = None,
                unit: str = "it") -> list:
    """``function`` of every one of ``items``, in ``workers`` threads with one PyTorch thread each
    (one: in turn, PyTorch's threads as they are); the results in order. ``bar``: a progress
    bar's description (on stderr, counting ``unit``, advanced as each result is taken in order;
    None: no bar)."""
    from tqdm import tqdm

    workers = max(1, min(workers, len(items)))
    with tqdm(total=len(items), desc=bar, unit=unit, disable=bar is None) as progress:
        if workers == 1:
            return [_advanced(progress, function(item)) for item in items]
        import torch

        before = torch.get_num_threads()
        torch.set_num_threads(1)
        try:
            with ThreadPoolExecutor(workers) as pool:
                return [_advanced(progress, result) for result in pool.map(function, items)]
        finally:
            torch.set_num_threads(before)


def _advanced(progress: Any, result: Any) -> Any:
    """``result``, the bar ``progress`` advanced by one."""
    progress.update(1)
    return result


def _fit_object(obj: SceneObject, cands: object, models: dict, options: FitOptions, screen: ScreenSettings) -> None:
    """Fit ``obj`` with its class (fills ``obj.model``, ``class_choice``, ``result``); where the
    screen leaves classes close, their full fits decide (``jsrte.fit.classes.fit_contenders``); a
    fit that explains almost none of its points is fitted again (:func:`refit_escaped`). A fit
    that fails is recorded in ``obj`` and the others go on."""
    from jsrte.fit import fit_recorded
    from jsrte.fit.classes import fit_contenders
    from jsrte.fit.screen import contending

    options = _held_to_floor(options, cands.segmentation.candidates[obj.candidate].floats)
    try:
        choice = obj.choice
        if isinstance(choice, str):
            raise JsrteError(choice)
        if len(models) == 1:
            (obj.model, model), = models.items()
            query = _query(cands, obj.candidate, options) if choice is None else choice.query
            obj.result = fit_recorded(model, query, options)
        else:
            query = choice.query
            obj.class_choice = choice.class_json()
            classes = contending(choice.classes, screen)
            if len(classes) == 1:
                obj.model = classes[0]
                obj.result = fit_recorded(models[obj.model], query, options, class_choice=obj.class_choice)
            else:
                obj.result = fit_contenders({name: query for name in classes}, models, options, obj.class_choice,
                                            settings=screen)
                obj.class_choice = obj.result.info["class"]
                obj.model = obj.class_choice["chosen"]
        refit_escaped(obj, query, models[obj.model], options)
    except JsrteError as exc:
        obj.status, obj.reason, obj.result = "failed", str(exc), None


def _held_to_floor(options: FitOptions, floats: bool) -> FitOptions:
    """``options`` for the full fits of a candidate: held to the floor by
    :data:`FLOATING_TOP_FLOOR_CONTACT` where it ``floats``, the preset fits by Adam and ``options``
    name no floor contact of their own."""
    if not floats or options.floor_contact is not None or options.settings().fit.solver != "adam":
        return options
    return options.changed(floor_contact=FLOATING_TOP_FLOOR_CONTACT)


def _check_objects(objects: list[SceneObject], models: dict, options: FitOptions, workers: int,
                   screen: ScreenSettings) -> list[SceneObject]:
    """Flag every fitted object of ``objects`` (:func:`flag_scene_object`), mark those no check
    finds (:func:`mark_unexplained`), and fit with another class those a check of
    :data:`ANOTHER_CLASS_AFTER` left unexplained (:func:`fit_another_class`), with every other
    close class those a check of :data:`IN_FULL_AFTER` did (:func:`fit_other_classes_in_full`),
    and search again with their own class those a check of :data:`SEARCHED_AGAIN_AFTER` still
    leaves so (:func:`search_again`). Returns the objects that search found."""
    for obj in objects:
        flag_scene_object(obj, options.seed)
        mark_unexplained(obj, models)
    _in_threads(lambda obj: fit_another_class(obj, models, options),
                [o for o in objects if o.unexplained_by in ANOTHER_CLASS_AFTER], workers)
    _in_threads(lambda obj: fit_other_classes_in_full(obj, models, options, screen),
                [o for o in objects if o.unexplained_by in IN_FULL_AFTER], workers)
    unseen = [o for o in objects if o.unexplained_by in SEARCHED_AGAIN_AFTER]
    _in_threads(lambda obj: search_again(obj, models, options), unseen, workers)
    return [o for o in unseen if o.status == "ok"]


LEFTOVER_DISTANCE_M = 0.05
"""A found object's point farther than this from its fitted surface is left over."""


def _fit_leftovers(objects: list[SceneObject], cands: object, models: dict, options: FitOptions,
                   screen: ScreenSettings, boxes: BoxSettings | None, workers: int,
                   views: CameraViews | None = None) -> list[SceneObject]:
    """The points of the found (``ok``) ``objects`` farther than :data:`LEFTOVER_DISTANCE_M`
    from their fitted surfaces, clustered again (``jsrte.scans.segment.leftover_candidates``):
    each cluster that may be an object becomes a candidate, a box where it is one, else
    screened, fitted and checked as the others. A chair pushed against a bed is segmented with
    it, and the bed's fit explains the bed's points, not the chair's. The new objects, numbered
    after ``objects``, each ``leftover_of`` the object most of its points came from."""
    segmented, seg = cands.segmented, cands.segmentation
    came_from = _add_leftover_candidates(objects, cands, models)
    if not came_from:
        return []
    new = list(came_from)
    cloud_points = np.asarray(segmented.cloud.points, float)
    found_boxes = {} if boxes is None else candidate_boxes(cands, new, boxes)
    to_screen = [k for k in new if k not in found_boxes] if len(models) > 1 else []
    screened = dict(_in_threads(lambda k: _screen_candidate(k, cands, models, options, screen), to_screen, workers))
    first = max(o.index for o in objects) + 1
    extra = [SceneObject(first + i, k, cloud_points[segmented.index[seg.candidates[k].index]],
                         choice=screened.get(k), box=found_boxes.get(k),
                         status=BOX_CLASS if k in found_boxes else "ok", leftover_of=came_from[k], views=views)
             for i, k in enumerate(new)]
    to_fit = [o for o in extra if o.box is None]
    _in_threads(lambda obj: _fit_object(obj, cands, models, options, screen), to_fit, workers)
    _check_objects(extra, models, options, workers, screen)
    return extra


PARTS_AFTER = ("seen through", "size", "share")
"""The checks (``SceneObject.unexplained_by``) after which a whole judged one object gives way to
its parts (:func:`_fit_parts_of_dropped`): no object of its class stands where its fit lies, or
none of its class's sizes, or its fit lies on few of its points, so it may be two objects, a bed
and the chair beside it fitted as one bed."""

FIRST_PARTS_AFTER = PARTS_AFTER + ("coverage", "top")
"""The checks after which a whole among the first fits (not a part fitted after its whole was
dropped) gives way to its parts: also where its points cover little of its fit, one shape laid
over two neighbours (a sofa and the table beside it fitted as one bed), or where they cover
little of the top of the table fitted (a sofa taken for a table: its parts are fitted without
the table's class). A part dropped so keeps its own parts out: a scrap of one of them, or the
same sofa again. On the tuning rooms 120-169 of seed 0 the scrap check found three more objects
(rooms 123 and 169) and no false detection more, the top check one more (room 143's sofa, F@5%
0.41, doubtful) at 70-120 s more a room where it acts; the parts of parts dropped so as well,
the top's class kept, found one more and made three false detections more."""


def _fit_parts_of_dropped(objects: list[SceneObject], cands: object, screened: dict[int, Choice | str],
                          boxes: dict[int, BoxEvidence], models: dict, options: FitOptions, screen: ScreenSettings,
                          workers: int, views: CameraViews | None = None) -> list[SceneObject]:
    """The parts of every whole among ``objects`` that a check of :data:`FIRST_PARTS_AFTER` left
    unexplained, fitted and checked as objects of their own (their quick fits from ``screened``,
    a box where ``boxes`` holds one; not of the class of a whole whose top its points did not
    cover), each ``part_of`` that whole; a part of those dropped by a check of
    :data:`PARTS_AFTER` in turn gives way to its own parts. New objects are numbered after
    ``objects``; a part's fit that is a second fit of an object found before goes."""
    seg = cands.segmentation
    taken = {o.candidate for o in objects} | {k for k, c in enumerate(seg.candidates) if c.rejected}
    added: list[SceneObject] = []
    dropped = [o for o in objects if o.unexplained_by in FIRST_PARTS_AFTER]
    while dropped:
        first = max(o.index for o in objects + added) + 1
        parts = [(k, whole.index) for whole in dropped for k in seg.candidates[whole.candidate].parts
                 if k not in taken]
        taken.update(k for k, _ in parts)
        screened = screened | _without_unseen_tops(parts, dropped, screened)
        new, searched = _candidates_fitted(parts, first, "part_of", cands, screened, boxes, models, options, screen,
                                           workers, views)
        drop_second_fits(objects + added + new, models, options.seed, newcomers=new)
        drop_second_fits(new, models, options.seed, newcomers=searched)
        drop_seen_through(new)
        added += new
        dropped = [o for o in new if o.unexplained_by in PARTS_AFTER]
    return added


def _without_unseen_tops(parts: list[tuple[int, int]], dropped: list[SceneObject],
                         screened: dict[int, Choice | str]) -> dict[int, Choice]:
    """The quick fits of ``parts`` (candidate, the index of its whole among ``dropped``) whose
    whole the top check dropped, without the class of that whole's fit (its score None) where
    another class has a score, so a sofa's part is not fitted again as the table whose top the
    scan did not see."""
    unseen = {w.index: w.model for w in dropped if w.unexplained_by == "top"}
    changed = {}
    for k, whole in parts:
        choice, name = screened.get(k), unseen.get(whole)
        if name is None or not isinstance(choice, Choice):
            continue
        others_scored = any(score is not None for other, score in choice.classes.items() if other != name)
        if others_scored and choice.classes.get(name) is not None:
            changed[k] = replace(choice, classes=choice.classes | {name: None})
    return changed


def _candidates_fitted(parts: list[tuple[int, int]], first: int, link: str, cands: object,
                       screened: dict[int, Choice | str], boxes: dict[int, BoxEvidence], models: dict,
                       options: FitOptions, screen: ScreenSettings, workers: int,
                       views: CameraViews | None = None) -> tuple[list[SceneObject], list[SceneObject]]:
    """Candidates as objects numbered from ``first``: each of ``parts`` (candidate, the index of
    the object it belongs to, set as the field ``link``) with its quick fits from ``screened``, a
    box where ``boxes`` holds one, else fitted (:func:`_fit_object`) and checked
    (:func:`_check_objects`). Returns the objects and those the checks' search found."""
    seg, segmented = cands.segmentation, cands.segmented
    cloud_points = np.asarray(segmented.cloud.points, float)
    new = [SceneObject(first + i, k, cloud_points[segmented.index[seg.candidates[k].index]], choice=screened.get(k),
                       box=boxes.get(k), status=BOX_CLASS if k in boxes else "ok", views=views, **{link: owner})
           for i, (k, owner) in enumerate(parts)]
    _in_threads(lambda obj: _fit_object(obj, cands, models, options, screen), [o for o in new if o.box is None],
                workers)
    return new, _check_objects(new, models, options, workers, screen)


PART_LEFT_SHARE = 0.25
"""A part of a found whole on fewer than this share of whose points the whole's fit lies is left
over by it (:func:`_fit_parts_left_over`): a chair segmented with the sofa it stands against and
fitted as one sofa leaves the chair's part off the sofa's surface. On the tuning rooms 100-119
of seed 0, the 59 parts of found wholes that are mostly the whole's object lay on 0.34 or more
of their points on its fit (the next on 0.71), the one part of another object (that chair) on
0.17; the bound lies midway."""


def _fit_parts_left_over(objects: list[SceneObject], cands: object, screened: dict[int, Choice | str],
                         boxes: dict[int, BoxEvidence], models: dict, options: FitOptions, screen: ScreenSettings,
                         workers: int, views: CameraViews | None = None) -> list[SceneObject]:
    """The parts of every found whole among ``objects`` (flagged or not) that its fit leaves over
    (on fewer than :data:`PART_LEFT_SHARE` of their points; a part it lies on is searched for such
    parts of its own), fitted and checked as objects of their own (their quick fits from
    ``screened``, a box where ``boxes`` holds one), each ``leftover_of`` that whole. Where one is
    found (or is a box), the whole's other parts (those it lies on, without the parts left over)
    are fitted and checked too, each ``part_of`` the whole, and where every one of them is found
    the whole gives way to its parts (``unexplained`` by "parts"); else the whole stays. New
    objects are numbered after ``objects``; of two new fits of one object the one on fewer of
    both's points goes, and a new fit that is a second fit of an object found before goes."""
    seg, segmented = cands.segmentation, cands.segmented
    cloud_points = np.asarray(segmented.cloud.points, float)
    taken = {o.candidate for o in objects} | {k for k, c in enumerate(seg.candidates) if c.rejected}

    def points_of(k: int) -> np.ndarray:
        return cloud_points[segmented.index[seg.candidates[k].index]]

    def split(whole: SceneObject, k: int) -> tuple[list[int], list[int]]:
        """Candidate ``k``'s parts left over by ``whole``'s fit, and its other parts."""
        left, rest = [], []
        for part in seg.candidates[k].parts:
            points = points_of(part)
            if points_on_fit(whole, points, models) < PART_LEFT_SHARE * len(points):
                left.append(part)
                continue
            inner_left, inner_rest = split(whole, part)
            left, rest = left + inner_left, rest + (inner_rest if inner_left else [part])
        return left, rest

    def as_objects(parts: list[tuple[int, SceneObject]], link: str) -> list[SceneObject]:
        """Candidates ``parts`` fitted and checked, each linked (``link``: the field) to its whole."""
        first = max((o.index for o in objects + added), default=-1) + 1
        new, searched = _candidates_fitted([(k, whole.index) for k, whole in parts], first, link, cands, screened,
                                           boxes, models, options, screen, workers, views)
        drop_second_fits(new, models, options.seed, newcomers=searched)
        drop_seen_through(new)
        return new

    added: list[SceneObject] = []
    wholes = [o for o in objects if o.status == "ok" and o.result is not None and seg.candidates[o.candidate].parts]
    splits = {whole.index: split(whole, whole.candidate) for whole in wholes}
    added += as_objects([(k, w) for w in wholes for k in splits[w.index][0] if k not in taken], "leftover_of")
    found = {o.leftover_of for o in added if o.status in ("ok", BOX_CLASS)}
    parting = [w for w in wholes if w.index in found and not taken.intersection(splits[w.index][1])]
    rest = as_objects([(k, w) for w in parting for k in splits[w.index][1]], "part_of")
    for whole in parting:
        parts = [o for o in rest if o.part_of == whole.index]
        if parts and all(o.status in ("ok", BOX_CLASS) for o in parts):
            whole.status, whole.unexplained_by = "unexplained", "parts"
            whole.reason = (f"fitted as its parts (objects {', '.join(str(o.index) for o in parts)}): its fit "
                            "left a part over")
    added += rest
    drop_second_fits(objects + added, models, options.seed, newcomers=added)
    return added


def _fit_split_wholes(objects: list[SceneObject], cands: object, screened: dict[int, Choice | str], covered: set[int],
                      models: dict, options: FitOptions, screen: ScreenSettings, views: CameraViews | None = None,
                      turned_down: dict[int, str] | None = None) -> list[SceneObject]:
    """Every whole the quick fits judged to hold several objects (in ``covered``, with parts) and
    that lies in no found object's candidate, a part of which stands for no object found and
    flagged ``ok`` (a bed's foot 36 cm from its head fitted as a bed off its place, its posts as
    nothing; a bed cut in two, its larger part fitted as a bed far from the true one), fitted in
    full as one object, smallest first, and flagged and checked as the others. It stands in the
    stead of the objects found among its parts when its fit is found (flagged ``ok``, or no worse
    than every one of them: ``doubtful`` where they all are), lies on :data:`FOUND_SHARE` of every
    part's points and on more of its own than those objects' fits lie on theirs, and is no second
    fit of another object: they become ``unexplained`` (pieces of it) and it leaves ``covered``;
    else ``turned_down`` (when given) says why, by candidate. Returns the wholes that stand,
    numbered after ``objects``."""
    candidates, segmented = cands.segmentation.candidates, cands.segmented
    cloud_points = np.asarray(segmented.cloud.points, float)
    added: list[SceneObject] = []

    def points_of(k: int) -> np.ndarray:
        return cloud_points[segmented.index[candidates[k].index]]

    def subtree(k: int) -> set[int]:
        return {k}.union(*(subtree(p) for p in candidates[k].parts))

    def found_in(k: int) -> list[SceneObject]:
        return [o for o in objects + added if o.status == "ok" and o.result is not None and o.candidate in subtree(k)]

    def stands_for_ok(part: int) -> bool:
        return any(o.result.flag == "ok" for o in found_in(part))

    def inside_found(k: int) -> bool:
        return any(k in subtree(o.candidate) - {o.candidate} for o in objects if o.status == "ok")

    wholes = sorted((k for k in covered
                     if candidates[k].parts and isinstance(screened.get(k), Choice) and not inside_found(k)),
                    key=lambda k: len(candidates[k].index))
    for k in wholes:
        if all(stands_for_ok(p) for p in candidates[k].parts):
            continue
        whole = SceneObject(max(o.index for o in objects + added) + 1, k, points_of(k), choice=screened[k], views=views)
        fit_whole_checked(whole, cands, models, options, screen)
        pieces = found_in(k)
        why = whole_turned_down(whole, [points_of(p) for p in candidates[k].parts],
                                sum(points_on_fit(o, o.points, models) for o in pieces),
                                [o.result.flag for o in pieces], models)
        if not why:
            others = [o for o in objects + added if o.status == "ok" and all(o is not p for p in pieces)]
            drop_second_fits(others + [whole], models, options.seed, newcomers=[whole])
            why = whole.reason if whole.status != "ok" else ""
        if why:
            if turned_down is not None:
                turned_down[k] = f"fitted whole as a {whole.model or 'shape'}, turned down: {why}"
            continue
        for piece in pieces:
            piece.status, piece.unexplained_by = "unexplained", "piece"
            piece.reason = f"a piece of object {whole.index}, one {whole.model} fitted to the whole it was cut from"
        covered.discard(k)
        added.append(whole)
    return added


def fit_whole_checked(whole: SceneObject, cands: object, models: dict, options: FitOptions,
                      screen: ScreenSettings) -> None:
    """Fit ``whole`` (its ``choice`` the quick fits of its candidate) as every object is fitted,
    flag it and run the checks that drop a fit (share, size, coverage, top, seen through)."""
    _fit_object(whole, cands, models, options, screen)
    if whole.result is None:
        return
    flag_scene_object(whole, options.seed)
    mark_unexplained(whole, models)
    drop_seen_through([whole])


def whole_turned_down(whole: SceneObject, parts: list[np.ndarray], on_pieces: int, piece_flags: list[str],
                      models: dict) -> str:
    """Why the fit of a whole judged to hold several objects does not stand in the stead of the
    objects found among its parts (:func:`_fit_split_wholes`; "" when it does): it must be found
    (``whole.status`` "ok"), flagged ``ok`` or no worse than every such object
    (``piece_flags``), lie on :data:`FOUND_SHARE` of each of ``parts`` (each (m, 3) a part's
    points) and on more of its points than those objects' fits lie on theirs (``on_pieces``, a
    count)."""
    if whole.status != "ok":
        return whole.reason or whole.status
    if whole.result.flag != "ok" and "ok" in piece_flags:
        return f"flagged {whole.result.flag}, where a piece's fit is ok"
    shares = [points_on_fit(whole, points, models) / max(len(points), 1) for points in parts]
    if min(shares) < FOUND_SHARE:
        return f"it lies on {min(shares):.0%} of a part's points (a found object on {FOUND_SHARE:.0%} or more)"
    on_whole = points_on_fit(whole, whole.points, models)
    if on_whole <= on_pieces:
        return f"it lies on {on_whole} points, its pieces' fits on {on_pieces}"
    return ""


def _add_leftover_candidates(objects: list[SceneObject], cands: object, models: dict) -> dict[int, int]:
    """Append to ``cands``' candidates the clusters of the points of the found ``objects``
    farther than :data:`LEFTOVER_DISTANCE_M` from their fitted surfaces; each new candidate's
    position -> the index of the object most of its points came from."""
    from jsrte.fit.quality import fitted_sdf
    from jsrte.scans.segment import leftover_candidates

    segmented, candidates = cands.segmented, cands.segmentation.candidates
    left, origin = [], []
    for obj in (o for o in objects if o.status == "ok" and o.result is not None):
        r = obj.result
        far = np.abs(fitted_sdf(models[obj.model].decoder, r.latent, r.transform, obj.points)) > LEFTOVER_DISTANCE_M
        left.append(candidates[obj.candidate].index[far])
        origin.append(np.full(int(far.sum()), obj.index))
    if not sum(map(len, left)):
        return {}
    index, origin = np.concatenate(left), np.concatenate(origin)
    points = np.asarray(segmented.cloud.points, float)[segmented.index]
    came_from = {}
    for c in leftover_candidates(index, points, segmented.heights(), segmented.up, SCENE_SEGMENT):
        values, counts = np.unique(origin[np.isin(index, c.index)], return_counts=True)
        came_from[len(candidates)] = int(values[np.argmax(counts)])
        candidates.append(c)
    return came_from


def json_ready(values: dict[str, Any]) -> dict[str, Any]:
    """``values`` with NumPy numbers as Python ones and non-finite floats as None."""
    out: dict[str, Any] = {}
    for key, value in values.items():
        if isinstance(value, (np.floating, float)):
            value = float(value) if np.isfinite(value) else None
        elif isinstance(value, np.integer):
            value = int(value)
        out[key] = value
    return out
