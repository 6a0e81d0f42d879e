"""Pictures: scene maps, snapshots, variants, heatmaps of generated trajectories.

Matplotlib with the Agg backend (no display needed). Every function draws into a given axes or
writes a PNG, and crops to a window around the scene's region of interest.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
from matplotlib.axes import Axes  # noqa: E402
from matplotlib.collections import LineCollection, PolyCollection  # noqa: E402
from matplotlib.colors import to_rgba  # noqa: E402
from matplotlib.figure import Figure  # noqa: E402
from matplotlib.patches import Ellipse, Polygon  # noqa: E402

from coster_sumo.core.scene import RoadMap, Scene  # noqa: E402
from coster_sumo.core.snapshot import AgentState  # noqa: E402
from coster_sumo.geometry.drivable import _corners  # noqa: E402

TARGET_COLOR = "#1f77b4"
ADVERSARY_COLOR = "#d62728"
OTHER_COLOR = "#7f7f7f"


def lay_out(fig: Figure) -> None:
    """``fig.tight_layout()`` once, and no layout engine left behind: matplotlib leaves a placeholder
    engine after ``tight_layout``, and with any engine set ``savefig`` draws the whole figure once more
    (without output) before the real drawing, a third of a render's time for the same pixels."""
    fig.tight_layout()
    fig.set_layout_engine(None)


def draw_map(ax: Axes, road_map: RoadMap, window: tuple[float, float, float, float] | None = None) -> None:
    """Lanes (thin grey centrelines), junctions (light fill), road edges (black)."""
    # one collection per kind of line: a few artists instead of two per lane (a city map's thousands
    # of artists made every render, its layout and its file several times slower), drawn alike
    polys = [poly for poly in road_map.junctions.points if len(poly) >= 3]
    if polys:
        ax.add_collection(PolyCollection(polys, closed=True, facecolor="#eeeeee", edgecolor="none", zorder=0))
    lanes = [(i, pts) for i, pts in enumerate(road_map.lanes.centerline)
             if window is None or not (pts[:, 0].max() < window[0] or pts[:, 0].min() > window[2]
                                       or pts[:, 1].max() < window[1] or pts[:, 1].min() > window[3])]
    if lanes:
        lines = [pts[:, :2] for _, pts in lanes]
        widths = [float(road_map.lanes.width[i]) * 2.0 for i, _ in lanes]
        ax.add_collection(LineCollection(lines, colors="#bbbbbb", linewidths=widths, alpha=0.35, capstyle="butt",
                                         joinstyle="round", zorder=1))
        ax.add_collection(LineCollection(lines, colors="#999999", linewidths=0.4, capstyle="projecting",
                                         joinstyle="round", zorder=1))
    edges = [pts[:, :2] for pts in road_map.road_edges.points]
    if edges:
        ax.add_collection(LineCollection(edges, colors="black", linewidths=0.6, capstyle="projecting",
                                         joinstyle="round", zorder=1))


def draw_box(ax: Axes, state: AgentState, color: str, alpha: float = 0.9, label: str | None = None,
             zorder: int = 5) -> None:
    """The box of ``state`` (its centre, heading and size) with a tick along its heading."""
    x, y, yaw, length, width = state.x, state.y, state.yaw, state.length, state.width
    c = _corners(np.array(x), np.array(y), np.array(yaw), np.array(length), np.array(width))
    ax.add_patch(Polygon(c, closed=True, facecolor=color, edgecolor="black", lw=0.5, alpha=alpha,
                         label=label, zorder=zorder))
    # heading tick
    ax.plot([x, x + 0.5 * length * np.cos(yaw)], [y, y + 0.5 * length * np.sin(yaw)], color="black",
            lw=0.6, zorder=zorder + 1)


def draw_agents(ax: Axes, scene: Scene, step: int, highlight: dict[int, str] | None = None) -> None:
    """Every vehicle at ``step`` as :func:`draw_box` draws one (``highlight``: agent -> colour, less
    transparent), all boxes in one collection and all heading ticks in another (two artists, not two
    per vehicle: a busy scene's boxes were a good part of a render's drawing and layout time)."""
    t = scene.tracks
    highlight = highlight or {}
    agents = np.flatnonzero(t.valid[:, step])
    if not len(agents):
        return
    x, y, yaw, length = t.x[agents, step], t.y[agents, step], t.heading[agents, step], t.length[agents, step]
    corners = _corners(x, y, yaw, length, t.width[agents, step])  # (N, 4, 2)
    alpha = [0.8 if int(a) in highlight else 0.5 for a in agents]  # a patch's alpha dims its edge too
    faces = [to_rgba(highlight.get(int(a), OTHER_COLOR), al) for a, al in zip(agents, alpha, strict=True)]
    edges = [to_rgba("black", al) for al in alpha]
    ax.add_collection(PolyCollection(list(corners), closed=True, facecolors=faces, edgecolors=edges, linewidths=0.5,
                                     zorder=5))
    ticks = np.stack([np.stack([x, y], -1), np.stack([x + 0.5 * length * np.cos(yaw),
                                                       y + 0.5 * length * np.sin(yaw)], -1)], 1)  # (N, 2, 2)
    ax.add_collection(LineCollection(list(ticks), colors="black", linewidths=0.6, capstyle="projecting",
                                     joinstyle="round", zorder=6))


CLASS_MARKS = {"pedestrian": "o", "cyclist": "D"}  # matplotlib markers of a VRU adversary


def draw_class_mark(ax: Axes, state: AgentState, adversary_class: str, labels: bool = True, zorder: int = 7) -> None:
    """A marker of the adversary's class at its centre (a pedestrian's 0.5 m box is a dot at map scale)."""
    mark = CLASS_MARKS.get(adversary_class)
    if mark is not None:
        ax.plot(state.x, state.y, marker=mark, ms=8, mfc="none", mec=ADVERSARY_COLOR, mew=1.5, ls="", zorder=zorder,
                label=adversary_class if labels else None)


def window_around(points: np.ndarray, margin: float = 25.0) -> tuple[float, float, float, float]:
    p = np.asarray(points, float).reshape(-1, 2)
    p = p[np.isfinite(p).all(axis=1)]
    lo, hi = p.min(axis=0) - margin, p.max(axis=0) + margin
    span = max(hi[0] - lo[0], hi[1] - lo[1])
    mid = 0.5 * (lo + hi)
    return (mid[0] - span / 2, mid[1] - span / 2, mid[0] + span / 2, mid[1] + span / 2)


def _finish(ax: Axes, window: tuple[float, float, float, float]) -> None:
    ax.set_xlim(window[0], window[2])
    ax.set_ylim(window[1], window[3])
    ax.set_aspect("equal")
    ax.set_xlabel("x [m]")
    ax.set_ylabel("y [m]")


def draw_ellipse(ax: Axes, target: AgentState) -> None:
    ax.add_patch(Ellipse((target.x, target.y), 4 * target.length, 4 * target.width,
                         angle=float(np.degrees(target.yaw)), fill=False, ls="--", color=TARGET_COLOR,
                         zorder=4))


def heatmap(ax: Axes, xy: np.ndarray, window: tuple[float, float, float, float], cells: int = 200,
            bandwidth_m: float = 1.0) -> None:
    """Kernel-density heatmap (Gaussian kernel of ``bandwidth_m`` on a grid) of points (..., 2)."""
    from scipy.ndimage import gaussian_filter

    p = np.asarray(xy, float).reshape(-1, 2)
    p = p[np.isfinite(p).all(axis=1)]
    h, xe, ye = np.histogram2d(p[:, 0], p[:, 1], bins=cells,
                               range=[[window[0], window[2]], [window[1], window[3]]])
    cell = (window[2] - window[0]) / cells
    dens = gaussian_filter(h.T, sigma=bandwidth_m / cell)
    dens = np.ma.masked_less_equal(dens, dens.max() * 1e-3)
    ax.imshow(dens, origin="lower", extent=(window[0], window[2], window[1], window[3]), cmap="magma_r",
              alpha=0.75, zorder=2)


@dataclass(frozen=True)
class AdversaryMarks:
    """What a variant's render draws of its adversary.

    Attributes:
        path_xy: (T, 2) [m] its path, solid.
        state: its box (at the render's step).
        contact_xy: [m] the first contact, a star (None: none; the close-up then centres on the box).
        planned_xy: (T, 2) [m] its plan, dashed (None: not drawn).
        box_label: the box's legend entry.
        adversary_class: vehicle, pedestrian or cyclist: the latter two get their class's mark over
            their small box.
    """

    path_xy: np.ndarray
    state: AgentState
    contact_xy: Sequence[float] | None = None
    planned_xy: np.ndarray | None = None
    box_label: str = "adversary at t_col"
    adversary_class: str = "vehicle"


def render_variant(path: Path, scene: Scene, target: int, t_col_step: int, title: str,
                   adversary: AdversaryMarks) -> Path:
    """One variant: map, agents at ``t_col_step`` of ``scene``, the target's path, the adversary's
    path and box, its plan dashed where it is given.

    Pass the injection pass as ``scene`` (with the adversary's driven path) to draw what was driven:
    a target that braked is then drawn where it was, not where the nominal pass had it.
    """
    adversary_xy, contact_xy, planned_xy = adversary.path_xy, adversary.contact_xy, adversary.planned_xy
    t = scene.tracks
    tv = t.valid[target]
    window = window_around(np.concatenate([adversary_xy, np.stack([t.x[target, tv], t.y[target, tv]], 1)]),
                           margin=15.0)
    fig, ax = plt.subplots(figsize=(7, 7.6))
    s = adversary.state
    focus = np.asarray(contact_xy if contact_xy is not None else (s.x, s.y), float)

    def draw(a: Axes, win: tuple[float, float, float, float], labels: bool) -> None:
        draw_map(a, scene.road_map, win)
        draw_agents(a, scene, t_col_step, {target: TARGET_COLOR})
        a.plot(t.x[target, tv], t.y[target, tv], color=TARGET_COLOR, lw=1.2, zorder=3,
               label="target path" if labels else None)
        if planned_xy is not None:
            a.plot(planned_xy[:, 0], planned_xy[:, 1], color=ADVERSARY_COLOR, lw=1.0, ls="--", zorder=3,
                   label="adversary's plan" if labels else None)
        a.plot(adversary_xy[:, 0], adversary_xy[:, 1], color=ADVERSARY_COLOR, lw=1.5, zorder=3,
               label="adversary path" if labels else None)
        draw_box(a, s, ADVERSARY_COLOR, label=adversary.box_label if labels else None)
        draw_class_mark(a, s, adversary.adversary_class, labels)
        if contact_xy is not None:  # hollow in the close-up, so the boxes under it stay visible
            a.plot(*contact_xy, marker="*", ms=14, color="gold", mec="black", zorder=8,
                   mfc="gold" if labels else "none", label="first contact" if labels else None)
        a.set_xlim(win[0], win[2])
        a.set_ylim(win[1], win[3])
        a.set_aspect("equal")

    draw(ax, window, True)
    # a 40 m close-up of the contact, in the corner of the picture that hides the fewest path points
    span = window[2] - window[0]
    if span > 160.0:  # below that a 40 m close-up would hardly magnify
        paths = np.concatenate([np.stack([t.x[target, tv], t.y[target, tv]], 1), adversary_xy[:, :2], focus[None]])
        rel = (paths - np.array(window[:2])) / span  # (n, 2) in [0, 1] over the picture
        corners = [(cx, cy) for cy in (0.02, 0.6) for cx in (0.02, 0.6)]
        hidden = [int(np.sum((rel[:, 0] > cx) & (rel[:, 0] < cx + 0.38) & (rel[:, 1] > cy) & (rel[:, 1] < cy + 0.38)))
                  for cx, cy in corners]
        cx, cy = corners[int(np.argmin(hidden))]
        inset = ax.inset_axes((cx, cy, 0.38, 0.38))
        draw(inset, (focus[0] - 20.0, focus[1] - 20.0, focus[0] + 20.0, focus[1] + 20.0), False)
        inset.set_xticks([])
        inset.set_yticks([])
        inset.text(0.03, 0.03, "40 m around the contact" if contact_xy is not None else "40 m around t_col",
                   transform=inset.transAxes, fontsize=7, va="bottom",
                   bbox={"facecolor": "white", "edgecolor": "none", "alpha": 0.8, "pad": 1.5})
        ax.indicate_inset_zoom(inset, edgecolor="black")
    ax.legend(loc="upper center", bbox_to_anchor=(0.5, -0.08), ncol=4, fontsize=8, frameon=False)
    ax.set_title(title, fontsize=10)
    _finish(ax, window)
    lay_out(fig)
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path


@dataclass(frozen=True)
class CollisionMoment:
    """What an overview shows of a collision snapshot.

    Attributes:
        t_col: [s] the collision time; step: its step in the scene drawn.
        target: the target's state at t_col; adversary: the adversary's (None: not drawn).
        entropy, times: the entropy curve over ``times`` [s] (None: no curve is drawn).
        region_xy, region_presence: (R, 2) region centres and the prior's presence at each (None: not drawn).
        adversary_class: vehicle, pedestrian or cyclist (a VRU is drawn with its class's mark).
    """

    t_col: float
    step: int
    target: AgentState
    adversary: AgentState | None = None
    entropy: Sequence[float] | None = None
    times: np.ndarray | None = None
    region_xy: np.ndarray | None = None
    region_presence: np.ndarray | None = None
    adversary_class: str = "vehicle"


def render_overview(path: Path, scene: Scene, target: int, moment: CollisionMoment,
                    representatives: Sequence[np.ndarray], samples_xy: np.ndarray | None = None) -> Path:
    """Map, agents at t_col, the ellipse, all representatives, heatmap of samples, entropy curve."""
    t_col_step, target_state, t_col = moment.step, moment.target, moment.t_col
    entropy, times, adversary = moment.entropy, moment.times, moment.adversary
    region_xy, region_presence = moment.region_xy, moment.region_presence
    pts = [np.array([[target_state.x, target_state.y]])] + [r[:, :2] for r in representatives]
    window = window_around(np.concatenate(pts), margin=25.0)
    has_curve = entropy is not None and times is not None and np.isfinite(np.asarray(entropy, float)).any()
    fig, axes = plt.subplots(1, 2 if has_curve else 1, figsize=(13 if has_curve else 7, 6.5),
                             gridspec_kw={"width_ratios": [1.4, 1]} if has_curve else None)
    ax = axes[0] if has_curve else axes
    draw_map(ax, scene.road_map, window)
    if samples_xy is not None and len(samples_xy):
        heatmap(ax, samples_xy, window)
    draw_agents(ax, scene, t_col_step, {target: TARGET_COLOR})
    draw_ellipse(ax, target_state)
    if region_xy is not None and region_presence is not None and len(region_xy):
        sc = ax.scatter(region_xy[:, 0], region_xy[:, 1], c=region_presence, cmap="viridis", s=18, zorder=3,
                        vmin=0.0, vmax=max(float(np.max(region_presence)), 1e-3))
        ax.figure.colorbar(sc, ax=ax, fraction=0.04, label="predicted presence probability")
    if adversary is not None:
        who = "adversary" if moment.adversary_class == "vehicle" else f"{moment.adversary_class} adversary"
        draw_box(ax, adversary, ADVERSARY_COLOR, label=f"{who} at t_col", zorder=7)
        draw_class_mark(ax, adversary, moment.adversary_class, labels=False, zorder=8)
    cmap = plt.get_cmap("tab10")
    for i, r in enumerate(representatives):  # above the boxes: a short path is not hidden under them
        ax.plot(r[:, 0], r[:, 1], color=cmap(i % 10), lw=1.6, label=f"variant {i}", zorder=9)
        ax.plot(r[0, 0], r[0, 1], "o", color=cmap(i % 10), mec="black", mew=0.5, ms=5, zorder=10)
    # what the picture's other marks are (they had no legend)
    from matplotlib.lines import Line2D
    from matplotlib.patches import Patch

    handles, _ = ax.get_legend_handles_labels()
    handles += [Patch(facecolor=TARGET_COLOR, edgecolor="black", label="target at t_col"),
                Patch(facecolor=OTHER_COLOR, edgecolor="black", alpha=0.5, label="other vehicles at t_col"),
                Line2D([], [], color=TARGET_COLOR, ls="--", label="ellipse of the collision-time regions"),
                Line2D([], [], color="grey", marker="o", ls="", mec="black", label="where a variant starts")]
    if samples_xy is not None and len(samples_xy):
        handles.append(Patch(facecolor=plt.get_cmap("magma_r")(0.6), alpha=0.75,
                             label=f"density of the {len(samples_xy)} oversampled paths"))
    ax.legend(handles=handles, loc="upper right", fontsize=7)
    ax.set_title(f"{scene.scenario_id}: target {scene.tracks.ids[target]}, t_col = {t_col:.1f} s",
                 fontsize=10)
    _finish(ax, window)
    if has_curve:
        ax2 = axes[1]
        e = np.asarray(entropy, float)
        ax2.plot(np.asarray(times), e, "o-", ms=3)
        ax2.axvline(t_col, color=ADVERSARY_COLOR, ls="--", label="t_col")
        ax2.set_xlabel("time [s]")
        ax2.set_ylabel("entropy of mean velocity distribution [nats]")
        ax2.legend()
    lay_out(fig)
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path


def training_history(metrics: dict) -> list[dict]:
    """The per-epoch records of a training metrics file (``train rollout``: ``epochs``; ``train
    prior``: ``history``); [] when it has none."""
    for key in ("epochs", "history"):
        rows = metrics.get(key)
        if isinstance(rows, list):  # the prior nests its held-out numbers: {"val": {"loss": ...}}
            return [{**r, **{f"val_{k}": v for k, v in r["val"].items()}} if isinstance(r.get("val"), dict) else r
                    for r in rows if isinstance(r, dict)]
    return []


def training_curves(runs: dict[str, list[dict]], path: str | Path, marks: dict[int, str] | None = None) -> Path:
    """Learning curves of one or more training runs into a PNG: losses (training and held-out)
    per epoch and, where the records have them, held-out minADE / minFDE. ``marks``: epoch ->
    label of a vertical line (where a run's learning rate dropped)."""
    keys_loss = ("train_loss", "val_loss")
    keys_err = ("val_minADE", "val_minFDE")
    has_err = any(k in r for rows in runs.values() for r in rows for k in keys_err)
    fig, axes = plt.subplots(1, 2 if has_err else 1, figsize=(12 if has_err else 6.5, 4.5), squeeze=False)
    cmap = plt.get_cmap("tab10")
    for i, (label, rows) in enumerate(runs.items()):
        epochs = np.arange(1, len(rows) + 1)
        for key, style in zip(keys_loss, ("--", "-"), strict=True):
            y = np.array([r.get(key, np.nan) for r in rows], float)
            if np.isfinite(y).any():
                axes[0, 0].plot(epochs, y, style, marker="o", ms=3, color=cmap(i % 10),
                                label=f"{label} {key.split('_')[0]}")
        if has_err:
            for key, style in zip(keys_err, ("-", ":"), strict=True):
                y = np.array([r.get(key, np.nan) for r in rows], float)
                if np.isfinite(y).any():
                    axes[0, 1].plot(epochs, y, style, marker="o", ms=3, color=cmap(i % 10),
                                    label=f"{label} {key[4:]}")
    axes[0, 0].set_xlabel("epoch")
    axes[0, 0].set_ylabel("loss")
    if all(r.get(k, 1.0) > 0 for rows in runs.values() for r in rows for k in keys_loss):
        axes[0, 0].set_yscale("log")  # the first epochs are ten times the rest
    axes[0, 0].set_title("training (dashed) and held-out (solid) loss", fontsize=10)
    axes[0, 0].legend(fontsize=8)
    if has_err:
        axes[0, 1].set_xlabel("epoch")
        axes[0, 1].set_ylabel("[m]")
        axes[0, 1].set_title("held-out minADE (solid) and minFDE (dotted)", fontsize=10)
        axes[0, 1].legend(fontsize=8)
    for ax in axes.ravel():
        ax.grid(alpha=0.3)
        for epoch, text in (marks or {}).items():
            ax.axvline(epoch - 0.5, color="0.4", lw=0.8, ls="--")  # between the last epoch before and the first after
            ax.annotate(text, (epoch - 0.5, 1.0), xycoords=("data", "axes fraction"), xytext=(-3, -3),
                        textcoords="offset points", ha="right", va="top", fontsize=8, color="0.3")
    lay_out(fig)
    out = Path(path)
    fig.savefig(out, dpi=100)
    plt.close(fig)
    return out
