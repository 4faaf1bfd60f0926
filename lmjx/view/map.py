"""The map view: the table, the arm in its failure's park pose (the locked joints at their
angles), the Reach-Ability map's cells at their true positions (one mesh per label, in
the colours of `lmjx.view.style`: PM green, NPM blue, unreachable grey), and, for a selected
cell, the edges whose whole arm acts over it (the map's spatial index): each edge's
interaction-point path, or the arm swept along it, coloured by a chosen quantity.  The
camera frames the cells and the arm; a legend says what each colour is.

A cell is selected by clicking it, with the GUI's cell picker, or at start (`select`).
Only the selected cell's edges are read from the file (`MapData.cell_edges`)."""

from __future__ import annotations

import threading
from dataclasses import dataclass
from typing import Any

import numpy as np

from lmjx.view import style
from lmjx.view.legend import Page, add_legend
from lmjx.view.mapdata import CellEdges, MapData
from lmjx.view.options import DRAWINGS, LABEL_SETS, QUANTITIES, SHOWN
from lmjx.view.shapes import ArmPoser, Mesh, arm_geoms, box, concatenate, geom_mesh, geom_rgb

SWEPT_POSES = 5  # arm poses drawn per edge when the arm is swept along it
SWEPT_CAP = 30  # edges drawn with the swept arm, at most (each is a mesh of its own)
CAP_MAX = 2000  # the slider's top: edges drawn at once


@dataclass(frozen=True)
class MapViewSettings:
    """What the map view shows first (each can be changed in the browser's GUI)."""

    cap: int = 100  # edges drawn over the selected cell, at most
    quantity: str = "duration"  # a key of QUANTITIES
    drawing: str = DRAWINGS[0]
    labels: str = LABEL_SETS[0]
    shown: str = SHOWN[0]
    select: tuple[int, int] | None = None  # (iy, ix); None: the cell the most edges act over


LEVELS = (("unreachable", 0, style.UNREACHABLE), ("npm", 1, style.NPM), ("pm", 2, style.PM))  # (node, label, colour)


def robot_qpos(robot) -> np.ndarray:
    return np.array([robot.mj.joint(n).qposadr[0] for n in robot.joint_names], np.int64)


def draw_arm(server: Any, root: str, poser: ArmPoser, q: np.ndarray) -> None:
    """The arm's drawn geoms (`shown_geoms`: its meshes, else its capsules) at `q`, under
    `root` (one node per geom, named after it)."""
    m = poser.m
    pos, quat = poser.poses(q)
    for g, p, w in zip(poser.geoms, pos, quat, strict=True):
        mesh = geom_mesh(m, int(g))
        assert mesh is not None
        rgb = style.ARM if max(geom_rgb(m, int(g))) > 128 else style.ARM_DARK  # the dark parts (fingers) stay dark
        server.scene.add_mesh_simple(f"{root}/{m.geom(int(g)).name or g}", mesh.vertices, mesh.faces, color=rgb,
                                     position=p, wxyz=w)  # fmt: skip


def draw_cells(server: Any, root: str, xs: np.ndarray, ys: np.ndarray, labels: np.ndarray, cell: float,
               visible: dict[str, bool] | None = None) -> dict[str, Any]:  # fmt: skip
    """The reach map's cells (labels (ny, nx) over the centres xs, ys) as thin tiles on the
    table, one mesh per label (`root`/unreachable, npm, pm: every tile of the label, placed;
    a mesh's one colour shows as given, where instanced colours show paler); `visible`: per
    node."""
    tile = box(np.array([style.CELL_FILL * cell / 2] * 2 + [style.CELL_HEIGHT / 2]))
    out = {}
    for name, level, rgb in LEVELS:
        iy, ix = np.nonzero(labels == level)
        centres = np.stack([xs[ix], ys[iy], np.full(len(iy), style.CELL_HEIGHT / 2)], axis=1).astype(np.float32)
        mesh = tiles(tile, centres)
        out[name] = server.scene.add_mesh_simple(
            f"{root}/{name}",
            mesh.vertices,
            mesh.faces,
            color=rgb,
            cast_shadow=False,
            receive_shadow=False,  # thin tiles on the table: their own shadows would speckle them
            visible=len(centres) > 0 and (visible or {}).get(name, True),
        )
    return out


def tiles(tile: Mesh, centres: np.ndarray) -> Mesh:
    """`tile` placed at each of `centres` (n, 3), as one mesh (a tile's vertices, in order,
    per centre); a degenerate empty mesh where there are none."""
    if not len(centres):
        return Mesh(np.zeros((3, 3), np.float32), np.array([[0, 1, 2]], np.uint32))
    v = (tile.vertices[None] + centres[:, None]).reshape(-1, 3).astype(np.float32)
    f = (tile.faces[None] + (np.arange(len(centres)) * len(tile.vertices))[:, None, None]).reshape(-1, 3)
    return Mesh(v, f.astype(np.uint32))


def cells_extent(xs: np.ndarray, ys: np.ndarray, cell: float) -> np.ndarray:
    """(4, 3) the corners of a reach map's grid on the table."""
    x0, x1, y0, y1 = xs[0] - cell / 2, xs[-1] + cell / 2, ys[0] - cell / 2, ys[-1] + cell / 2
    return np.array([[x, y, 0.0] for x in (x0, x1) for y in (y0, y1)])


def arm_extent(poser: ArmPoser, q: np.ndarray) -> np.ndarray:
    """(6 n, 3) the extreme points of the arm's drawn geoms' bounding spheres at `q`."""
    pos, _ = poser.poses(q)
    r = poser.m.geom_rbound[poser.geoms][:, None, None] * np.concatenate([np.eye(3), -np.eye(3)])[None]
    return (pos[:, None] + r).reshape(-1, 3)


class MapView:
    """Draws a map (`MapData`) into a viser server's scene, with its GUI; `select` draws the
    edges over a cell.  Every scene node lives under /map."""

    def __init__(self, server: Any, data: MapData, settings: MapViewSettings = MapViewSettings()) -> None:
        from lmjx.planner.clearance import park_pose

        self.server = server
        self.data = data
        self.settings = settings
        self.lock = threading.Lock()
        robot = data.robot
        m = robot.mj
        bodies = {m.body(b).name for b in range(1, m.nbody)}
        self.poser = ArmPoser(m, robot_qpos(robot), arm_geoms(m, bodies))
        self.park = park_pose(robot, data.failure)
        self.selected: CellEdges | None = None
        self.cap, self.quantity, self.drawing = settings.cap, settings.quantity, settings.drawing
        self._swept: list[str] = []
        extent = np.concatenate([cells_extent(data.xs, data.ys, data.cell), arm_extent(self.poser, self.park)])
        self.camera = style.fit_camera(extent, style.MAP_CAMERA)
        style.set_camera(server, self.camera)
        self.page = Page(
            f"Reach-Ability map {data.path.name}",
            (f"{data.robot.key}, failure {data.failure.describe()}; {data.ny} x {data.nx} cells of "
             f"{data.cell * 100:g} cm, {data.n_edges:,} edges", "The edges over the selected cell (red)."),
            ("pm", "npm", "unreachable", "arm", "selected", "edges", "table"),
        )  # fmt: skip
        self._draw_table()
        self._draw_arm()
        self._draw_cells(settings.labels, settings.shown)
        self._gui()
        start = settings.select if settings.select is not None else data.busiest_cell()
        if start is not None:
            self.select(*start)

    # ------------------------------------------------------------------ the still scene
    def _draw_table(self) -> None:
        arm = self.data.robot.arm
        mesh = box(np.asarray(arm.table_half))
        self.server.scene.add_mesh_simple(
            "/map/table", mesh.vertices, mesh.faces, color=style.TABLE, position=tuple(arm.table_center)
        )

    def _draw_arm(self) -> None:
        draw_arm(self.server, "/map/arm", self.poser, self.park)

    def _draw_cells(self, which: str, shown: str) -> None:
        labels = self.data.labels_smooth if which == "smoothed" else self.data.labels
        pm_only = shown != SHOWN[0]
        visible = {"npm": not pm_only, "unreachable": not pm_only}
        self.cells = draw_cells(self.server, "/map/cells", self.data.xs, self.data.ys, labels, self.data.cell, visible)
        for handle in self.cells.values():
            handle.on_click(self._clicked)

    def _clicked(self, event: Any) -> None:
        """A click on a cell: where the ray meets the tiles' top selects the cell there."""
        o, d = np.asarray(event.ray_origin), np.asarray(event.ray_direction)
        if abs(d[2]) < 1e-9:
            return
        t = (style.CELL_HEIGHT - o[2]) / d[2]
        hit = self.data.cell_at(*(o + t * d)[:2])
        if hit is not None:
            self.select(*hit)

    # ------------------------------------------------------------------ the GUI
    def _gui(self) -> None:
        gui, d = self.server.gui, self.data
        counts = d.edge_count()
        gui.add_markdown(
            f"**{d.path.name}**: {d.robot.key}, failure {d.failure.describe()}  \n"
            f"{d.ny} x {d.nx} cells of {d.cell * 100:g} cm; {d.n_edges:,} edges"
        )
        add_legend(self.server, self.page)
        with gui.add_folder("Cells"):
            labels = gui.add_dropdown("Labels", LABEL_SETS, initial_value=self.settings.labels)
            shown = gui.add_dropdown("Show", SHOWN, initial_value=self.settings.shown)
            self.pick_iy = gui.add_slider("Cell row (iy)", min=0, max=max(d.ny - 1, 1), step=1, initial_value=0)
            self.pick_ix = gui.add_slider("Cell column (ix)", min=0, max=max(d.nx - 1, 1), step=1, initial_value=0)
            go = gui.add_button("Select this cell")
            busiest = gui.add_button("Cell with the most edges", disabled=not counts.size or counts.max() == 0)
        with gui.add_folder("Edges"):
            cap = gui.add_slider("Edges drawn (at most)", min=1, max=CAP_MAX, step=1, initial_value=self.cap)
            quantity = gui.add_dropdown("Colour by", tuple(QUANTITIES), initial_value=self.quantity)
            drawing = gui.add_dropdown("Draw", DRAWINGS, initial_value=self.drawing)
            self.legend = gui.add_markdown("Click a cell, or pick one above.")

        def relabel(_: Any) -> None:
            with self.lock:
                self._draw_cells(labels.value, shown.value)

        labels.on_update(relabel)

        def reshow(_: Any) -> None:
            for name in ("npm", "unreachable"):
                self.cells[name].visible = shown.value == SHOWN[0]

        shown.on_update(reshow)
        go.on_click(lambda _: self.select(int(self.pick_iy.value), int(self.pick_ix.value)))

        def select_busiest(_: Any) -> None:
            cell = d.busiest_cell()
            if cell is not None:
                self.select(*cell)

        busiest.on_click(select_busiest)

        def restyle(_: Any) -> None:
            self.cap, self.quantity, self.drawing = int(cap.value), quantity.value, drawing.value
            if self.selected is not None:
                self.select(self.selected.iy, self.selected.ix)

        for control in (cap, quantity, drawing):
            control.on_update(restyle)

    # ------------------------------------------------------------------ a selected cell
    def select(self, iy: int, ix: int) -> CellEdges:
        """Draw the edges over cell (iy, ix) (reading only theirs from the file)."""
        with self.lock:
            arm = self.drawing == DRAWINGS[1]
            cap = min(self.cap, SWEPT_CAP) if arm else self.cap
            sel = self.data.cell_edges(iy, ix, cap, self.quantity, arm=arm)
            self.selected = sel
            self._draw_selection(sel, arm)
            self.pick_iy.value, self.pick_ix.value = iy, ix
            return sel

    def _draw_selection(self, sel: CellEdges, arm: bool) -> None:
        d, scene = self.data, self.server.scene
        x, y = float(d.xs[sel.ix]), float(d.ys[sel.iy])
        s = d.cell
        ring = np.array(
            [[x - s / 2, y - s / 2], [x + s / 2, y - s / 2], [x + s / 2, y + s / 2], [x - s / 2, y + s / 2]]
        )
        z = style.CELL_HEIGHT + 0.002
        pts = np.array([[[*ring[k], z], [*ring[(k + 1) % 4], z]] for k in range(4)], np.float32)
        scene.add_line_segments("/map/selected/outline", pts, colors=style.SELECTED, thickness=0.004)
        tile = box(np.array([s / 2, s / 2, style.CELL_HEIGHT]))
        scene.add_mesh_simple(
            "/map/selected/tile", tile.vertices, tile.faces, color=style.SELECTED, position=(x, y, 0.0)
        )
        for name in self._swept:
            scene.remove_by_name(name)
        self._swept = []
        colours = style.colormap(sel.values)
        if not arm:
            drawn = [(p, c) for p, c in zip(sel.p, colours, strict=True) if len(p) > 1]
            segs = [np.stack([p[:-1], p[1:]], axis=1) for p, _ in drawn]
            cols = [np.broadcast_to(c, (len(p) - 1, 2, 3)) for p, c in drawn]
            if segs:
                scene.add_line_segments(
                    "/map/edges/paths",
                    np.concatenate(segs).astype(np.float32),
                    colors=np.concatenate(cols).astype(np.uint8),
                    thickness=style.PATH_THICKNESS,
                    thickness_units="screen",
                )
            else:
                scene.remove_by_name("/map/edges/paths")
        else:
            scene.remove_by_name("/map/edges/paths")
            for k, (q, c) in enumerate(zip(sel.q, colours, strict=True)):
                picks = np.unique(np.linspace(0, len(q) - 1, SWEPT_POSES).round().astype(int))
                mesh = concatenate([self.poser.mesh(x) for x in q[picks]])
                name = f"/map/edges/swept/{k}"
                scene.add_mesh_simple(name, mesh.vertices, mesh.faces, color=tuple(int(v) for v in c), opacity=0.35)
                self._swept.append(name)
        self.legend.content = self._legend(sel, x, y)

    def _legend(self, sel: CellEdges, x: float, y: float) -> str:
        d = self.data
        label = ("unreachable", "NPM", "PM")[int(d.labels_smooth[sel.iy, sel.ix])]
        lines = [f"**Cell (iy {sel.iy}, ix {sel.ix})** at x {x:.3f} m, y {y:.3f} m: {label}"]
        if not d.has_edges:
            lines.append("This map has no edges (a reach map alone).")
        elif not len(sel.ids):
            lines.append("No edge acts over this cell.")
        else:
            _, text, unit = QUANTITIES[sel.quantity]
            lo, hi = float(sel.values.min()), float(sel.values.max())
            shown = "swept arms" if self.drawing == DRAWINGS[1] else "paths"
            lines.append(f"{len(sel.ids):,} edges act here; {len(sel.drawn):,} drawn ({shown}, evenly spaced by id).")
            lines.append(f"Colour: {text} from {lo:.3g} (cyan) to {hi:.3g}{' ' + unit if unit else ''} (magenta).")
        return "  \n".join(lines)
