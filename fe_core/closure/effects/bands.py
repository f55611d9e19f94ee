"""Stiffness bands: the stiffness factor of a set of cells (:class:`ElementBand`), the sets it is used on
(plate joints, patches of cells around nodes, named cell sets) and the factories that build them for a
model.

Cell effects need a mesh and its element matrices (:func:`has_cell_stiffness`); their factories return
None for any other model.
"""

from __future__ import annotations

import re
from collections.abc import Sequence

import numpy as np
import scipy.sparse as sp

from ...assembly import SegmentedMatrix, cell_dofs
from ...elements.hex8 import element_stiffness
from ...model import ParametricModel, check_parameters
from .base import Effect, Terms, _free_position, candidate_nodes

__all__ = ["ElementBand", "PatchBands", "has_cell_stiffness", "joint_bands", "patch_bands", "patch_centres"]


def _segment_cells(model: ParametricModel) -> list[np.ndarray]:
    if model.cell_segment is not None:
        return [np.flatnonzero(model.cell_segment == i) for i in range(len(model.segment_names))]
    try:
        return [model.mesh.cell_sets[name] for name in model.segment_names]
    except KeyError as exc:
        raise ValueError(f"segment {exc.args[0]!r} is not a cell set of the mesh; element bands need "
                         f"the segments' cells") from exc


def has_cell_stiffness(model: ParametricModel) -> bool:
    """True if the model can give its cells' element stiffness (a mesh with known elements and materials)."""
    return model.mesh is not None and (model.cell_stiffness is not None
                                       or (model.material is not None and model.formulation is not None))


def _cells_stiffness(model: ParametricModel, cells: np.ndarray) -> np.ndarray:
    """Element stiffness matrices of ``cells`` at alpha = 0, shape (c, d, d), N/m.

    From the model's own ``cell_stiffness`` (a model file: any element family and
    material per cell), else hex8 with the model's material; the benchmark's 544
    cells are computed once and cached on the model.
    """
    if not has_cell_stiffness(model):
        where = f" ({model.source})" if model.source else ""
        raise ValueError(f"effects on a set of cells need the element matrices of a mesh; this model{where} "
                         + ("has no mesh (it is given as matrices)" if model.mesh is None else
                            "does not give them (several materials without cell_stiffness)"))
    if model.cell_stiffness is not None:
        return model.cell_stiffness(cells)
    Ke = getattr(model, "_cell_stiffness_cache", None)
    if Ke is None:
        Ke = model._cell_stiffness_cache = element_stiffness(model.mesh.cell_coords, model.material.D,
                                                             model.formulation)
    return Ke[cells]


def _band_matrix(model: ParametricModel, cells: np.ndarray, owner: np.ndarray) -> SegmentedMatrix:
    """The stiffness of ``cells`` on the free DOFs, split by the segment owning each cell (cells
    in no segment are the fixed part, not scaled by alpha).

    Assembled directly on the free DOFs from the cached element matrices (entries on a
    constrained DOF dropped): a few milliseconds per band, so hundreds of patches cost
    well under a second.
    """
    Ke = _cells_stiffness(model, cells)  # (c, d, d)
    dofs = _free_position(model)[cell_dofs(model.mesh.cells[cells])]  # (c, d), -1 = constrained
    d = dofs.shape[1]
    rows = np.repeat(dofs, d, axis=1).ravel()
    cols = np.tile(dofs, (1, d)).ravel()
    m = model.n_segments
    seg = np.repeat(np.where(owner[cells] >= 0, owner[cells], m), d * d)  # row m: cells in no segment
    keep = (rows >= 0) & (cols >= 0)
    rows, cols, seg, vals = rows[keep], cols[keep], seg[keep], Ke.ravel()[keep]
    n = model.n_dofs
    keys, slot = np.unique(rows.astype(np.int64) * n + cols, return_inverse=True)
    data = np.bincount(seg * keys.size + slot, weights=vals, minlength=(m + 1) * keys.size).reshape(m + 1, -1)
    counts = np.bincount(keys // n, minlength=n)
    pattern = sp.csr_matrix((data.sum(axis=0), (keys % n).astype(np.int32),
                             np.concatenate([[0], np.cumsum(counts)])), shape=(n, n))
    fixed = data[m] if np.any(owner[cells] < 0) else None
    return SegmentedMatrix(pattern=pattern, data=data[:m], fixed=fixed)


class ElementBand(Effect):
    """Stiffness factor of a band of elements: their K_e (1 + alpha_s) -> K_e (1 + alpha_s)(1 + beta).

    ``beta > -1`` keeps K positive definite. ``bands`` maps a location label
    to the cells of that band; the plate joints of the benchmark are one use
    (:func:`joint_bands`), any set of cells is another.
    """

    kind = "element_band"
    parameters = ("beta",)
    units = ("-",)
    lower = (-1.0,)
    #: A band more than twice as stiff as the plate it is part of needs material the model lacks (a
    #: stiffener), not damage or a joint's flexibility: implausible by default (``set_limits`` widens it).
    upper = (1.0,)
    scale = (0.1,)
    margin = (1e-3,)

    def __init__(self, model: ParametricModel, bands: dict[str, np.ndarray], kind: str | None = None):
        super().__init__(model)
        if kind:
            self.kind = kind
        _cells_stiffness(model, np.zeros(0, dtype=int))  # refuses a model without element matrices
        self.bands = {label: np.asarray(cells, dtype=int) for label, cells in bands.items()}
        seg_cells = _segment_cells(model)
        owner = np.full(model.mesh.n_cells, -1)
        for s, cells in enumerate(seg_cells):
            owner[cells] = s
        self._owner = owner
        self._matrices: dict[str, SegmentedMatrix] = {}
        for label, cells in self.bands.items():
            if cells.size == 0:
                raise ValueError(f"element band {label!r} has no cells")
            self._matrices[label] = _band_matrix(model, cells, owner)

    def locations(self) -> list[str]:
        return list(self.bands)

    def add(self, bands: dict[str, np.ndarray]) -> list[str]:
        """Add bands (labels not yet present); returns the labels added, now locations too."""
        new = [label for label in bands if label not in self.bands and np.size(bands[label])]
        for label in new:
            self.bands[label] = np.asarray(bands[label], dtype=int)
            self._matrices[label] = _band_matrix(self.model, self.bands[label], self._owner)
        if new:
            self._locset = None  # Effect.check's cached location set
        return new

    def _resolve(self, location: str) -> None:
        """A location this effect can make but has not yet (a refined patch named by a stored step or another
        process's screen): made on first use. Nothing for an effect without a maker."""
        if location not in self._matrices and self.maker is not None:
            self.add(self.maker(location))

    #: Builds the bands of an unknown label (``{label: cells}``, empty if the label is not one it makes).
    maker = None

    def check(self, location: str, values) -> np.ndarray:
        self._resolve(location)
        return super().check(location, values)

    def refine(self, best: Sequence[str]) -> list[str]:
        """More locations around the best-screened ``best`` (see :class:`PatchBands`); none for a fixed set."""
        return []

    def band_stiffness(self, alpha, location) -> sp.csr_matrix:
        """The band's share of ``K(alpha)``, N/m."""
        alpha = check_parameters(alpha, self.model.n_segments, "alpha")
        self._resolve(location)
        return self._matrices[location].combine(1.0 + alpha)

    def terms(self, alpha, location, values) -> Terms:
        return Terms(stiffness=float(values[0]) * self.band_stiffness(alpha, location))

    def alpha_derivative(self, alpha, location, values, index) -> Terms:
        self._resolve(location)
        return Terms(stiffness=float(values[0]) * self._matrices[location].segment(index))

    def position(self, location) -> np.ndarray:
        self._resolve(location)
        return self.model.mesh.centroids_of(self.bands[location]).mean(axis=0)

    def describe(self, location) -> dict:
        self._resolve(location)
        cells = self.bands[location]
        c = self.model.mesh.centroids_of(cells)
        return {"cells": int(cells.size), "x_min_m": float(c[:, 0].min()), "x_max_m": float(c[:, 0].max())}


def patch_bands(model: ParametricModel, centres: Sequence[int], rings: Sequence[int] = (1, 2)) -> dict[str, np.ndarray]:
    """Cells within ``r`` rings of each centre node (ring 1: the cells touching it), labelled
    ``node <n> r<r>``: patches for damage localisation anywhere."""
    cells = model.mesh.cells
    bands = {}
    for n in centres:
        nodes = np.array([n])
        for r in range(1, max(rings) + 1):
            inside = np.flatnonzero(np.any(np.isin(cells, nodes), axis=1))
            if r in rings:
                bands[f"node {int(n)} r{r}"] = inside
            nodes = np.unique(cells[inside])
    return bands


def patch_centres(model: ParametricModel, n_target: int = 160) -> np.ndarray:
    """About ``n_target`` patch centres spread over any mesh: the node nearest the mean of the free
    nodes in each box of a grid, refined until that many boxes hold nodes."""
    nodes = candidate_nodes(model, node_set="")
    xyz = model.mesh.nodes[nodes]
    lo = xyz.min(axis=0)
    h = float(np.ptp(xyz, axis=0).max())
    while True:
        boxes, which = np.unique(np.floor((xyz - lo) / h).astype(np.int64), axis=0, return_inverse=True)
        if boxes.shape[0] >= min(n_target, nodes.size) or h <= 0:
            break
        h /= 1.25
    which = which.ravel()
    mean = np.zeros((boxes.shape[0], 3))
    np.add.at(mean, which, xyz)
    mean /= np.bincount(which)[:, None]
    dist = np.linalg.norm(xyz - mean[which], axis=1)
    order = np.lexsort((dist, which))  # per box, nearest first
    first = order[np.r_[True, np.diff(which[order]) != 0]]
    return np.sort(nodes[first])


#: On a mesh without a ``top`` node set, every free node is a patch centre while there are at most this many
#: (the plate of issue 28's own cases has 495, its frame 855: 990 and 1,710 patches, built in 1.3 and 2.1 s,
#: screened in 1.2 and 1.8 s); a larger mesh starts from :func:`patch_centres`' spread of about 160 and refines
#: round the best of each screen (:class:`PatchBands`).
ALL_CENTRES_MAX = 2500
#: Refinement: round each of the ``REFINE_BEST`` best-screened patches, every free node within ``REFINE_REACH``
#: times the patch's radius (its farthest node from the centre) becomes a centre, at most ``REFINE_MAX`` new
#: centres a screen (the nearest first).
REFINE_BEST, REFINE_REACH, REFINE_MAX = 5, 2.0, 600
_LABEL = re.compile(r"node (\d+) r(\d+)")


class PatchBands(ElementBand):
    """Patches of cells round centre nodes (``node <n> r<r>``: the cells within r rings of node n) whose set
    of centres can grow: :meth:`refine` adds the free nodes round the best-screened patches as centres, and a
    label of a free node not yet a centre (a refined patch named by a stored step or by another process's
    screen) is made on first use. The screening calls :meth:`refine` (:func:`fe_core.closure.screening.screen`):
    a coarse set of centres, then every node near the best of them, so that a damaged patch round any node
    is a candidate without screening every node of a large mesh."""

    def __init__(self, model: ParametricModel, centres: Sequence[int], rings: Sequence[int] = (1, 2),
                 refinable: bool = True):
        self.rings = tuple(int(r) for r in rings)
        self.refinable = refinable
        self.free = np.asarray(candidate_nodes(model, node_set=""), dtype=int)
        super().__init__(model, patch_bands(model, centres, self.rings), kind="patch")
        self._tree = None

    def maker(self, location: str) -> dict[str, np.ndarray]:
        hit = _LABEL.fullmatch(location)
        if hit is None or int(hit.group(2)) not in self.rings or int(hit.group(1)) not in set(self.free.tolist()):
            return {}
        return patch_bands(self.model, [int(hit.group(1))], self.rings)

    def centres(self) -> np.ndarray:
        return np.unique([int(_LABEL.fullmatch(label).group(1)) for label in self.bands])

    def refine(self, best: Sequence[str]) -> list[str]:
        """Patches centred on every free node near the ``best`` patches (at most :data:`REFINE_MAX` new centres,
        the nearest first); returns the new locations."""
        if not self.refinable or not best:
            return []
        from scipy.spatial import cKDTree

        nodes = self.model.mesh.nodes
        if self._tree is None:
            self._tree = cKDTree(nodes[self.free])
        have = set(self.centres().tolist())
        found: dict[int, float] = {}
        for label in best:
            hit = _LABEL.fullmatch(label)
            if hit is None:
                continue
            centre = int(hit.group(1))
            cells = self.bands.get(label)
            reach = REFINE_REACH * float(np.linalg.norm(nodes[np.unique(self.model.mesh.cells[cells])]
                                                        - nodes[centre], axis=1).max())
            for k in self._tree.query_ball_point(nodes[centre], reach):
                n = int(self.free[k])
                if n not in have:
                    d = float(np.linalg.norm(nodes[n] - nodes[centre]))
                    found[n] = min(d, found.get(n, np.inf))
        new = sorted(found, key=lambda n: (found[n], n))[:REFINE_MAX]
        return self.add(patch_bands(self.model, sorted(new), self.rings))


def _patch_factory(model: ParametricModel, stride: int = 2) -> Effect | None:
    """Patches of 1 and 2 rings of cells around centre nodes: on a model with a ``top`` node set (the
    benchmark) every ``stride``-th top node in x and y (a 2 x 2 subgrid of the top surface: neighbouring
    patches overlap, so no damage falls between them), a fixed set; on any other mesh every free node (up
    to :data:`ALL_CENTRES_MAX` of them: a damaged patch round a surface node is then a candidate itself, not
    stood in for by one a few elements away), else :func:`patch_centres`, refined round the best of each
    screen (:class:`PatchBands`). None for a model without element matrices (matrices only)."""
    if not has_cell_stiffness(model):
        return None
    if "top" in model.mesh.node_sets:
        top = candidate_nodes(model, "top")
        xy = np.round(model.mesh.nodes[top, :2], 9)
        xs, ys = np.unique(xy[:, 0]), np.unique(xy[:, 1])
        keep = np.isin(xy[:, 0], xs[::stride]) & np.isin(xy[:, 1], ys[::stride])
        return ElementBand(model, patch_bands(model, top[keep]), kind="patch")
    free = candidate_nodes(model, node_set="")
    if free.size <= ALL_CENTRES_MAX:
        return PatchBands(model, free, refinable=False)
    return PatchBands(model, patch_centres(model))


def _cell_set_factory(model: ParametricModel) -> Effect | None:
    """The stiffness factor of every named cell set of the mesh (``set <name>``), except sets made of
    whole segments (their factor is a combination of the alphas); None if there is none."""
    if not has_cell_stiffness(model):
        return None
    segments = _segment_cells(model)
    owner = np.full(model.mesh.n_cells, -1)
    for s, cells in enumerate(segments):
        owner[cells] = s
    bands = {}
    for name, cells in model.mesh.cell_sets.items():
        cells = np.asarray(cells, dtype=int)
        touched = np.unique(owner[cells])
        whole = touched.min() >= 0 and sum(segments[t].size for t in touched) == np.unique(cells).size
        if cells.size and not whole:
            bands[f"set {name}"] = cells
    return ElementBand(model, bands, kind="cell_set") if bands else None


def joint_bands(model: ParametricModel, joints_x: Sequence[float], atol: float = 1e-9) -> dict[str, np.ndarray]:
    """Cells touching each joint plane ``x = x_j``: one band per joint, labelled ``joint x=<mm> mm``."""
    nodes_x = model.mesh.nodes[:, 0]
    bands = {}
    for xj in joints_x:
        on_plane = np.abs(nodes_x - xj) <= atol
        cells = np.flatnonzero(np.any(on_plane[model.mesh.cells], axis=1))
        if cells.size == 0:
            raise ValueError(f"no cells touch the plane x = {xj} m")
        bands[f"joint x={1e3 * xj:g} mm"] = cells
    return bands


def _block_joints(model: ParametricModel) -> list[float]:
    """x of the planes where consecutive ``plate<k>`` cell sets meet (the benchmark's joints)."""
    names = sorted((n for n in model.mesh.cell_sets if n.startswith("plate") and n[5:].isdigit()),
                   key=lambda n: int(n[5:]))
    joints = []
    for left, right in zip(names, names[1:]):
        a = np.unique(model.mesh.cells[model.mesh.cell_sets[left]])
        b = np.unique(model.mesh.cells[model.mesh.cell_sets[right]])
        shared = np.intersect1d(a, b)
        xs = np.unique(np.round(model.mesh.nodes[shared, 0], 9))
        if xs.size == 1:
            joints.append(float(xs[0]))
    return joints


def _joint_factory(model: ParametricModel) -> Effect | None:
    if not has_cell_stiffness(model):
        return None
    joints = _block_joints(model)
    if not joints:
        return None
    return ElementBand(model, joint_bands(model, joints), kind="joint_band")
