"""``jsrte view``: an interactive 3D viewer in the browser, served locally with ``viser``.

The scene holds, for the selected fit: the scan's points (subsampled, coloured by distance to
the fitted surface), the retrieved mesh, the true mesh where known, the floor plane, and the
poses of the winning and the other hypotheses (axes at each pose's origin, as long as half the
canonical unit sphere's radius at that pose's scale). The GUI panel toggles each layer, steps
through the fits and lists each fit's numbers. In a scene, the other objects' meshes are shown
too (grey).
"""

from __future__ import annotations

import contextlib
import io
import signal
import socket
import threading
from collections.abc import Callable, Iterator
from typing import Any

import numpy as np

from jsrte.errors import JsrteError
from jsrte.view.display import FAR_FRACTION, coloured_scan, decimated
from jsrte.view.loading import Collection, FitItem, Pose, load_item

MAX_POINTS = 30_000
"""Scan points drawn per fit."""
MAX_FACES = 60_000
"""Triangles drawn per mesh (decimated beyond)."""
MESH_COLOUR = (240, 140, 60)
TRUTH_COLOUR = (60, 190, 90)
OTHER_COLOUR = (170, 170, 170)
LAYERS = ("scan points", "retrieved mesh", "true mesh", "floor", "winning pose", "other hypotheses",
          "other objects")


def check_port_free(host: str, port: int) -> None:
    """Refuse, with a one-line error, a port some other program already listens on."""
    if port == 0:
        return
    try:
        family, kind, proto, _, address = socket.getaddrinfo(host, port, type=socket.SOCK_STREAM)[0]
    except socket.gaierror as exc:
        raise JsrteError(f"cannot serve on host {host!r} ({exc.strerror}); pass --host 127.0.0.1") from None
    with socket.socket(family, kind, proto) as probe:
        probe.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        try:
            probe.bind(address)
        except OSError as exc:
            raise JsrteError(f"port {port} on {host} is already in use ({exc.strerror}); pass --port with a free "
                             f"port, e.g. --port {port + 1}") from None


class Viewer:
    """The scene and GUI of one viser server, for the fits of a collection.

    Items are read on first selection and kept; every scene change happens under one lock
    (GUI callbacks run on viser's threads).
    """

    def __init__(self, server: Any, collection: Collection, *, warn: Callable[[str], None] = print) -> None:
        self.server, self.collection, self.warn = server, collection, warn
        self.items: dict[int, FitItem] = {}
        self.index = 0
        self.lock = threading.RLock()
        self.nodes: list[Any] = []
        self.layers: dict[str, list[Any]] = {name: [] for name in LAYERS}
        self._build_gui()

    # -- items ----------------------------------------------------------------------------------
    def item(self, index: int) -> FitItem:
        """The fit at ``index``, read now if it was not yet (its problems printed once)."""
        if index not in self.items:
            item = load_item(self.collection.entries[index], max_scan_points=200_000)
            for problem in item.problems:
                self.warn(problem)
            self.items[index] = item
        return self.items[index]

    # -- GUI ------------------------------------------------------------------------------------
    def _build_gui(self) -> None:
        gui = self.server.gui
        names = [e.name for e in self.collection.entries]
        self.title = gui.add_markdown(f"**{self.collection.kind}** {self.collection.path.name}")
        with gui.add_folder("Fits" if self.collection.kind != "scene" else "Objects"):
            self.dropdown = gui.add_dropdown("fit", _unique(names), initial_value=_unique(names)[0],
                                             disabled=len(names) == 1)
            self.previous = gui.add_button("previous", disabled=len(names) == 1)
            self.next = gui.add_button("next", disabled=len(names) == 1)
        with gui.add_folder("Numbers"):
            self.numbers = gui.add_markdown("")
        with gui.add_folder("Layers"):
            self.toggles = {name: gui.add_checkbox(name, name != "other hypotheses") for name in LAYERS
                            if name != "other objects" or self.collection.kind == "scene"}
        self.legend = gui.add_markdown("")
        options = list(self.dropdown.options)
        self.dropdown.on_update(lambda _: self.show(options.index(self.dropdown.value)))
        self.previous.on_click(lambda _: self._step(-1))
        self.next.on_click(lambda _: self._step(+1))
        for name, box in self.toggles.items():
            box.on_update(lambda _, name=name: self._set_visible(name))

    def _step(self, delta: int) -> None:
        options = list(self.dropdown.options)
        self.dropdown.value = options[(self.index + delta) % len(options)]  # its callback shows it

    def _set_visible(self, layer: str) -> None:
        with self.lock:
            for node in self.layers[layer]:
                node.visible = self.toggles[layer].value

    # -- scene ----------------------------------------------------------------------------------
    def show(self, index: int) -> None:
        """Draw the fit at ``index`` (replacing what was drawn)."""
        with self.lock:
            item = self.item(index)
            self.index = index
            for node in self.nodes:
                node.remove()
            self.nodes, self.layers = [], {name: [] for name in LAYERS}
            up = item.up if item.up is not None else np.array([0.0, 1.0, 0.0])
            self.server.scene.set_up_direction(tuple(float(x) for x in up))
            centre, radius = _extent(item)
            self._draw_scan(item, radius)
            self._draw_meshes(item)
            self._draw_floor(item, centre, radius)
            self._draw_poses(item.poses)
            if self.collection.kind == "scene":
                self._draw_other_objects(index)
            for layer in self.toggles:
                self._set_visible(layer)
            self.numbers.content = _numbers_markdown(item)
            self._place_camera(centre, radius, up)

    def _add(self, layer: str, node: Any) -> None:
        self.nodes.append(node)
        self.layers[layer].append(node)

    def _draw_scan(self, item: FitItem, radius: float) -> None:
        if item.scan is None:
            self.legend.content = ""
            return
        points = coloured_scan(item.scan, item.mesh, MAX_POINTS)
        self._add("scan points", self.server.scene.add_point_cloud(
            "/scan", points.points, points.colours, point_size=0.008 * radius, point_shape="circle"))
        self.legend.content = ("" if item.mesh is None else
                               f"Scan points: blue on the fitted surface, yellow at {points.far / 2 * 100:.1f} cm, "
                               f"red from {points.far * 100:.1f} cm ({FAR_FRACTION:.0%} of the mesh's radius).")

    def _draw_meshes(self, item: FitItem) -> None:
        scene = self.server.scene
        if item.mesh is not None:
            mesh = decimated(item.mesh, MAX_FACES)
            self._add("retrieved mesh", scene.add_mesh_simple("/fit", np.asarray(mesh.vertices, np.float32),
                                                              np.asarray(mesh.faces, np.uint32), color=MESH_COLOUR,
                                                              side="double"))
        if item.truth is not None:
            truth = decimated(item.truth, MAX_FACES)
            self._add("true mesh", scene.add_mesh_simple("/truth", np.asarray(truth.vertices, np.float32),
                                                         np.asarray(truth.faces, np.uint32), color=TRUTH_COLOUR,
                                                         opacity=0.3, side="double"))

    def _draw_floor(self, item: FitItem, centre: np.ndarray, radius: float) -> None:
        if item.floor is None:
            return
        normal = item.floor.normal
        on_floor = centre - (centre @ normal - item.floor.offset) * normal
        size = 6.0 * radius
        self._add("floor", self.server.scene.add_grid(
            "/floor", width=size, height=size, plane="xy", cell_size=size / 24, section_size=size / 6,
            wxyz=_quaternion_from_z(normal), position=on_floor, plane_color=(225, 225, 225), plane_opacity=0.5))

    def _draw_poses(self, poses: list[Pose]) -> None:
        from viser import transforms

        scene = self.server.scene
        for pose in poses:
            if pose.winner:
                self._add("winning pose", scene.add_frame(
                    "/poses/winner", wxyz=transforms.SO3.from_matrix(pose.rotation).wxyz,
                    position=pose.translation, axes_length=0.5 * pose.scale, axes_radius=0.02 * pose.scale))
        others = [p for p in poses if not p.winner]
        if others:
            self._add("other hypotheses", scene.add_batched_axes(
                "/poses/others", np.stack([transforms.SO3.from_matrix(p.rotation).wxyz for p in others]),
                np.stack([p.translation for p in others]), np.array([p.scale for p in others]),
                axes_length=0.35, axes_radius=0.008))

    def _draw_other_objects(self, index: int) -> None:
        for other in range(len(self.collection.entries)):
            item = self.item(other)
            if other != index and item.mesh is not None:
                mesh = decimated(item.mesh, MAX_FACES // 4)
                self._add("other objects", self.server.scene.add_mesh_simple(
                    f"/others/{other}", np.asarray(mesh.vertices, np.float32), np.asarray(mesh.faces, np.uint32),
                    color=OTHER_COLOUR, side="double"))

    def _place_camera(self, centre: np.ndarray, radius: float, up: np.ndarray) -> None:
        """Look at the object from 3 radii away, raised 30° above the floor."""
        side = np.cross(up, [1.0, 0.0, 0.0] if abs(up[0]) < 0.9 else [0.0, 0.0, 1.0])
        side /= np.linalg.norm(side)
        direction = np.cos(np.radians(30)) * side + np.sin(np.radians(30)) * up
        camera = self.server.initial_camera
        camera.look_at = tuple(float(x) for x in centre)
        camera.position = tuple(float(x) for x in centre + 3.0 * radius * direction)
        camera.up = tuple(float(x) for x in up)
        for client in self.server.get_clients().values():
            client.camera.look_at = camera.look_at
            client.camera.position = camera.position
            client.camera.up_direction = camera.up


def _unique(names: list[str]) -> list[str]:
    """Names made unique for the dropdown (a counter appended to repeats)."""
    seen: dict[str, int] = {}
    out = []
    for name in names:
        seen[name] = seen.get(name, 0) + 1
        out.append(name if seen[name] == 1 else f"{name} ({seen[name]})")
    return out


def _extent(item: FitItem) -> tuple[np.ndarray, float]:
    """(3,) centre and radius (scan units) of what to look at: the mesh, else the scan's bulk."""
    for geometry in (item.mesh, item.truth):
        if geometry is not None:
            v = np.asarray(geometry.vertices)
            centre = (v.min(axis=0) + v.max(axis=0)) / 2
            return centre, max(float(np.linalg.norm(v - centre, axis=1).max()), 1e-6)
    if item.scan is not None and len(item.scan):
        lo, hi = np.percentile(item.scan, [5, 95], axis=0)
        return (lo + hi) / 2, max(float(np.linalg.norm(hi - lo)) / 2, 1e-6)
    return np.zeros(3), 1.0


def _quaternion_from_z(normal: np.ndarray) -> tuple[float, float, float, float]:
    """wxyz of the shortest rotation taking +z to the unit vector ``normal``."""
    z = np.array([0.0, 0.0, 1.0])
    axis = np.cross(z, normal)
    s, c = np.linalg.norm(axis), float(z @ normal)
    if s < 1e-9:
        return (1.0, 0.0, 0.0, 0.0) if c > 0 else (0.0, 1.0, 0.0, 0.0)
    half = np.arctan2(s, c) / 2
    xyz = axis / s * np.sin(half)
    return (float(np.cos(half)), float(xyz[0]), float(xyz[1]), float(xyz[2]))


def _numbers_markdown(item: FitItem) -> str:
    rows = "\n".join(f"| {k} | {v} |" for k, v in item.numbers.items())
    text = f"**{item.name}**\n\n| | |\n|---|---|\n{rows}\n" if rows else f"**{item.name}**\n"
    if item.problems:
        text += "\n" + "\n".join(f"- missing: {p}" for p in item.problems)
    return text


def serve(collection: Collection, *, host: str = "127.0.0.1", port: int = 8080,
          say: Callable[[str], None] = print, warn: Callable[[str], None] = print,
          stop: threading.Event | None = None) -> None:
    """Serve the viewer until Ctrl-C (SIGINT), SIGTERM or ``stop`` is set.

    ``say`` gets one line with the URL once the first fit's scene is built. Raises
    ``JsrteError`` when the port is taken or the first fit cannot be read at all.
    """
    import viser

    check_port_free(host, port)
    with contextlib.redirect_stdout(io.StringIO()):  # viser prints a banner of its own
        server = viser.ViserServer(host=host, port=port, verbose=False, label="jsrte")
    stop = stop or threading.Event()
    try:
        if port != 0 and server.get_port() != port:
            raise JsrteError(f"port {port} on {host} is already in use; pass --port with a free port, "
                             f"e.g. --port {port + 1}")
        viewer = Viewer(server, collection, warn=warn)
        first = next((i for i in range(len(collection.entries)) if viewer.item(i).fit_read), None)
        if first is None:
            raise JsrteError(f"no fit could be read ({viewer.item(0).problems[0]})", collection.path)
        viewer.show(first)
        if first:  # its callback draws it again: harmless
            viewer.dropdown.value = list(viewer.dropdown.options)[first]
        with _stopped_by_signals(stop):
            shown = "localhost" if host in ("0.0.0.0", "::") else f"[{host}]" if ":" in host else host
            say(f"jsrte view: {len(collection.entries)} fit{'s' * (len(collection.entries) != 1)} at "
                f"http://{shown}:{server.get_port()} (Ctrl-C to stop)")
            while not stop.wait(0.25):
                pass
    finally:
        with contextlib.redirect_stdout(io.StringIO()):
            server.stop()


@contextlib.contextmanager
def _stopped_by_signals(stop: threading.Event) -> Iterator[None]:
    """Within: Ctrl-C (SIGINT) and SIGTERM set ``stop`` (on the main thread; elsewhere only ``stop`` does)."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    handlers = {sig: signal.signal(sig, lambda *_: stop.set()) for sig in (signal.SIGINT, signal.SIGTERM)}
    try:
        yield
    finally:
        for sig, handler in handlers.items():
            signal.signal(sig, handler)
