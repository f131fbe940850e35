"""Dense correspondence between the ICT Face Model's skin and the template's topology, and the transfer of
ICT shapes (the mean, identity modes, expressions) onto the template's vertices.

Registration (:func:`register`, deterministic: numpy and scipy only, fixed schedule):

1. **Rims.** The ICT skin (:mod:`rig.ict.data`) has four boundary loops: both eyelid rims, the lip rim
   and the bottom of the neck; the template has the same three rims (where its skin meets the eye pockets
   and the mouth bag). ICT's lip rim lies deep inside the mouth (the lips ~11 mm apart there), so the
   template's lip rim goes to ICT's lip *contact line* instead (:class:`IctRims`), and ICT's inner-lip
   triangles inside it are not used. Each rim is split at its two corners into an upper and a lower half (ICT's with
   :func:`rig.template.rim_loop`, the template's are stored so) and the template's rim vertices are matched
   to the ICT rim at equal normalised arc length: 2 x ``n_eye`` + ``n_mouth`` landmark pairs.
2. **Frame.** ICT's data is brought into the rig frame by the rigid transform (rotation and translation,
   no scale: the heads keep ICT's real size) that best maps its rim points onto the template's.
3. **Non-rigid ICP** of the template's skin (the connected skin, with its eye pockets and mouth bag) onto
   the ICT mean: after a similarity fit on the rims, :data:`SCHEDULE` steps minimise
   ``sum_i w_i |x_i - c_i|^2 + RIM_WEIGHT sum_rim |x_j - r_j|^2 + alpha |L (x - x0)|^2`` (one sparse linear
   solve per step; ``c_i``: the closest point of the ICT surface to vertex ``i``, kept where it is within
   :data:`MAX_DISTANCE_MM` and the normals agree within 60 degrees; ``L``: the uniform graph Laplacian;
   ``x0``: the similarity-fitted template; ``alpha`` falling).
4. **Correspondence.** Every vertex of the :data:`COVERED_REGIONS` whose final closest point is accepted
   is *covered*: it stores that point's ICT triangle and barycentric coordinates.

Transfer (:class:`Transfer`): a field on ICT's vertices (an identity mode, an expression, or the mean's
positions) becomes a displacement on the template's vertices, linearly:

- covered vertices: the field interpolated at their ICT surface point;
- the rest of the connected skin (eye pockets, mouth bag, ears, uncovered spots at the rims): the harmonic
  continuation of the covered displacements (``L d = 0`` on them, the covered ones fixed; ``L`` weighted by
  ``1 / length^2`` of the template's edges, so that a tight crease such as the lid margin moves as one), a
  smooth continuation that keeps MakeHuman's shape of those parts;
- eyeballs: moved rigidly, by the mean displacement of their eyelid rim (the mean and identity modes: so
  the eyeball keeps its fit to the lids) or by ICT's eyeball centre (expressions, where the lids close over
  a still eyeball);
- teeth and tongue (separate pieces): each moved rigidly by the mean displacement of the skin vertices
  nearest to its vertices.

Units: mm; ICT's own frame for the model's data, the rig frame for the result.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import scipy.sparse as sp
import scipy.sparse.linalg as spla

from rig.errors import SetupError
from rig.geometry import Similarity, closest_surface_points, face_normals, mesh_edges, vertex_normals
from rig.ict.data import IctModel
from rig.template import REGION_NAMES, TemplateMesh, ordered_loop, rim_halves, rim_loop

__all__ = [
    "COVERED_REGIONS",
    "MAX_DISTANCE_MM",
    "RIM_WEIGHT",
    "SCHEDULE",
    "Registration",
    "Transfer",
    "IctRims",
    "boundary_loops",
    "ict_rims",
    "register",
    "rim_targets",
]

COVERED_REGIONS: tuple[str, ...] = (
    "scalp",
    "forehead",
    "brows",
    "eyelids",
    "nose",
    "cheeks",
    "lips",
    "chin",
    "jaw",
    "neck",
)
"""Regions whose vertices take their position from the ICT surface; the ears (ICT's are coarse: the head
and neck part has 1,839 vertices) and the hidden parts are continued."""
RIGID_PIECES: tuple[str, ...] = ("eyeballs", "teeth", "tongue")
SCHEDULE: tuple[tuple[float, int], ...] = ((100.0, 4), (30.0, 4), (10.0, 4), (3.0, 4), (1.0, 4), (0.3, 4))
"""Non-rigid ICP: ``(alpha, steps)``: the Laplacian weight and how many closest-point updates at it."""
RIM_WEIGHT = 10.0
MAX_DISTANCE_MM = 10.0
MIN_NORMAL_COS = 0.5


def boundary_loops(faces: np.ndarray) -> list[np.ndarray]:
    """The boundary loops of a triangle mesh, each in walking order (:func:`rig.template.ordered_loop`)."""
    e = np.sort(np.concatenate([faces[:, [0, 1]], faces[:, [1, 2]], faces[:, [2, 0]]]), 1)
    uniq, count = np.unique(e, axis=0, return_counts=True)
    edges = uniq[count == 1]
    # split into connected loops
    parent = {int(v): int(v) for v in np.unique(edges)}

    def find(a):
        while parent[a] != a:
            parent[a] = parent[parent[a]]
            a = parent[a]
        return a

    for a, b in edges.tolist():
        parent[find(a)] = find(b)
    roots = np.array([find(int(a)) for a in edges[:, 0]])
    return [ordered_loop(edges[roots == r]) for r in sorted(set(roots.tolist()))]


def _arc(points: np.ndarray) -> np.ndarray:
    s = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(points, axis=0), axis=1))])
    return s / max(s[-1], 1e-12)


def _resample(polyline: np.ndarray, t: np.ndarray) -> np.ndarray:
    """Points at normalised arc lengths ``t`` along ``polyline`` ``(n, 3)``."""
    s = _arc(polyline)
    return np.stack([np.interp(t, s, polyline[:, k]) for k in range(3)], 1)


def _hops(num: int, faces: np.ndarray, sources: np.ndarray) -> np.ndarray:
    """Edge hops ``(num,)`` of every vertex from the nearest of ``sources`` (``inf`` where unreachable)."""
    from scipy.sparse.csgraph import dijkstra

    e = mesh_edges(faces)
    g = sp.coo_matrix((np.ones(len(e)), (e[:, 0], e[:, 1])), shape=(num, num)).tocsr()
    return dijkstra(g, directed=False, unweighted=True, indices=sources, min_only=True)


def _ring_loop(vertices: np.ndarray, edges: np.ndarray, ring: np.ndarray) -> np.ndarray | None:
    """The vertices ``ring`` ``(V,)`` bool as one loop in :func:`rig.template.rim_loop` order (``edges``
    ``(E, 2)`` the mesh's), or None where their edges do not form one simple loop."""
    try:
        return rim_loop(vertices, ordered_loop(edges[ring[edges].all(1)]))
    except SetupError:
        return None


def _lip_gap(vertices: np.ndarray, loop: np.ndarray, samples: int = 39) -> float:
    """Mean distance (mm) between a mouth loop's upper and lower rims at equal normalised arc lengths."""
    upper, lower = rim_halves(vertices, loop)
    t = np.linspace(0.0, 1.0, samples + 2)[1:-1]
    return float(np.linalg.norm(_resample(vertices[upper], t) - _resample(vertices[lower], t), axis=1).mean())


@dataclass(frozen=True)
class IctRims:
    """ICT's rims on its mean (vertex ids in :func:`rig.template.rim_loop` order) and the triangles inside
    its lips.

    Attributes:
        left_eye, right_eye: ``(n,)`` the eyelid rims (boundary loops of ICT's skin), left is +X.
        mouth: ``(m,)`` the lip *contact line*: ICT's skin ends deep inside the mouth (its boundary loop there
            has the lips ~11 mm apart at the midline); the contact line is the edge ring around that loop (the
            vertices at the same number of edge hops from it) whose upper and lower rims are closest (mean gap
            at equal arc length; ring 6 of ICT's light model, 0.59 mm), which is where the template's lip rim
            (its skin meeting the mouth bag, the lips 1.4 mm apart) belongs.
        inner: ``(T,)`` bool over ICT's skin triangles: those inside the contact line (the inner lips that the
            template's mouth bag continues); the registration does not use them.
    """

    left_eye: np.ndarray
    right_eye: np.ndarray
    mouth: np.ndarray
    inner: np.ndarray


def ict_rims(ict: IctModel) -> IctRims:
    """ICT's rims and inner-lip triangles (:class:`IctRims`), from its mean's topology and shape."""
    v = ict.neutral
    loops = boundary_loops(ict.triangles)
    if len(loops) != 4:
        raise SetupError(f"ICT skin: expected 4 boundary loops (eyes, mouth, neck), found {len(loops)}")
    centre = np.array([v[lp].mean(0) for lp in loops])
    neck = int(np.argmin(centre[:, 1]))
    rest = [i for i in range(4) if i != neck]
    mouth = min(rest, key=lambda i: abs(centre[i, 0]))
    eyes = [i for i in rest if i != mouth]
    left = max(eyes, key=lambda i: centre[i, 0])
    right = min(eyes, key=lambda i: centre[i, 0])
    hops = _hops(len(v), ict.triangles, loops[mouth])
    edges = mesh_edges(ict.triangles)
    rings = []
    for r in range(0, 64):
        loop = _ring_loop(v, edges, hops == r)
        if loop is None:
            break
        rings.append((_lip_gap(v, loop), r, loop))
    if not rings:
        raise SetupError("ICT skin: the mouth's boundary is not a simple loop")
    _, ring, contact = min(rings, key=lambda g: (g[0], g[1]))
    return IctRims(
        left_eye=rim_loop(v, loops[left]),
        right_eye=rim_loop(v, loops[right]),
        mouth=contact,
        inner=(hops[ict.triangles] < ring).all(1),
    )


def rim_targets(
    template: TemplateMesh, ict: IctModel, head: np.ndarray | None = None, rims: IctRims | None = None
) -> tuple[np.ndarray, np.ndarray]:
    """Template rim vertex ids ``(R,)`` and their points on ICT's rims ``(R, 3)`` (ICT's frame, mm), matched
    half-rim by half-rim at equal normalised arc length: the eyelid rims and the lip contact line
    (:class:`IctRims`, ``rims`` or found on the mean); the points lie on ``head`` ``(N, 3)`` (default: the
    mean)."""
    ours = {"left_eye": template.eye_loops[0], "right_eye": template.eye_loops[1], "mouth": template.mouth_loop}
    theirs = ict_rims(ict) if rims is None else rims
    head = ict.neutral if head is None else np.asarray(head, float)
    ids, points = [], []
    for name, loop in ours.items():
        their_loop = getattr(theirs, name)
        for our_half, their_half in zip(rim_halves(template.vertices, loop), rim_halves(ict.neutral, their_loop)):
            t = _arc(template.vertices[our_half])
            ids.append(our_half)
            points.append(_resample(head[their_half], t))
    ids_all, pts = np.concatenate(ids), np.concatenate(points)
    _, first = np.unique(ids_all, return_index=True)  # the corners appear in both halves
    first = np.sort(first)
    return ids_all[first], pts[first]


def _laplacian(n: int, faces: np.ndarray, vertices: np.ndarray | None = None) -> sp.csr_matrix:
    """Graph Laplacian ``(n, n)``: ``(L x)_i = x_i - weighted mean of its neighbours``; uniform weights, or
    ``1 / length^2`` of each edge on ``vertices`` ``(n, 3)`` (so that the two sides of a tight crease, a
    fraction of a mm apart, move together)."""
    e = mesh_edges(faces)
    if vertices is None:
        w = np.ones(len(e))
    else:
        w = 1.0 / np.maximum(np.sum((vertices[e[:, 0]] - vertices[e[:, 1]]) ** 2, axis=1), 1e-6)
    a = sp.coo_matrix((w, (e[:, 0], e[:, 1])), shape=(n, n))
    a = (a + a.T).tocsr()
    deg = np.asarray(a.sum(1)).ravel()
    return (sp.identity(n, format="csr") - sp.diags(1.0 / np.maximum(deg, 1e-12)) @ a).tocsr()


def _pieces(template: TemplateMesh) -> tuple[np.ndarray, np.ndarray]:
    """``(V,)`` bool of the connected skin (every vertex not in an eyeball, tooth or tongue) and ``(F,)`` bool
    of its faces."""
    rigid = np.isin(template.regions, [REGION_NAMES.index(r) for r in RIGID_PIECES])
    skin = ~rigid
    return skin, skin[template.faces].all(1)


@dataclass(frozen=True)
class Registration:
    """The template registered to the ICT mean.

    Attributes:
        rotation: ``(3, 3)``; translation: ``(3,)`` mm: ICT's frame -> the rig frame before placement,
            ``x_rig = rotation @ x_ict + translation``.
        covered: ``(C,)`` int64 template vertex ids that take their position from the ICT surface.
        triangle: ``(C,)`` int64 row of ICT's skin triangles; barycentric: ``(C, 3)`` float64.
        registered: ``(V_skin, 3)`` float64 the non-rigid ICP result (rig frame, before projection), for
            the report.
        distance: ``(C,)`` float64 distance of each covered vertex's ICP position to its ICT point, mm.
    """

    rotation: np.ndarray
    translation: np.ndarray
    covered: np.ndarray
    triangle: np.ndarray
    barycentric: np.ndarray
    registered: np.ndarray
    distance: np.ndarray


def register(template: TemplateMesh, ict: IctModel, target: np.ndarray | None = None) -> Registration:
    """Register the template (MakeHuman's shape) to an ICT head (module docstring).

    Args:
        template: the MakeHuman template (its regions, rims and topology; vertices mm, rig frame).
        ict: the ICT model (its triangles, rims and neutral, which sets the frame).
        target: ``(N, 3)`` the ICT head to register to, ICT's frame, mm (default: the neutral mean). The
            frame comes from the mean's rims whatever the target, so registrations of different heads are
            comparable.
    """
    ict_rim = ict_rims(ict)
    rims, rim_points = rim_targets(template, ict, rims=ict_rim)
    # the frame: rigid, from the points on the mean's rims to the template's rim vertices
    frame = Similarity.fit(rim_points, template.vertices[rims])
    rot, trans = frame.rotation, frame.translation
    head = ict.neutral if target is None else np.asarray(target, float)
    surface = head @ rot.T + trans
    if target is not None:  # the target's own rim points, at the mean's arc-length positions along its rims
        _, rim_points = rim_targets(template, ict, head, ict_rim)
    goal = rim_points @ rot.T + trans
    # the surface searched: ICT's skin without the inner lips (inside the contact line)
    outer = np.flatnonzero(~ict_rim.inner)
    outer_tris = ict.triangles[outer]
    skin, skin_faces = _pieces(template)
    sid = np.flatnonzero(skin)
    local = np.full(len(template.vertices), -1)
    local[sid] = np.arange(len(sid))
    faces = local[template.faces[skin_faces]]
    lap = _laplacian(len(sid), faces)
    sim = Similarity.fit(template.vertices[rims], goal, with_scale=True)
    x0 = sim.apply(template.vertices[sid])
    x = x0.copy()
    data_ids = np.isin(template.regions[sid], [REGION_NAMES.index(r) for r in COVERED_REGIONS + ("ears",)])
    rim_local = local[rims]
    s_rim = sp.coo_matrix((np.ones(len(rims)), (np.arange(len(rims)), rim_local)), shape=(len(rims), len(sid)))
    ltl = (lap.T @ lap).tocsc()
    stl = (s_rim.T @ s_rim).tocsc()
    lx0 = ltl @ x0
    srhs = s_rim.T @ goal
    tri_normals = face_normals(surface, outer_tris)
    for alpha, steps in SCHEDULE:
        for _ in range(steps):
            found = closest_surface_points(x, surface, outer_tris)
            normals = vertex_normals(x, faces)
            ok = (
                data_ids
                & (found.distance < MAX_DISTANCE_MM)
                & ((normals * tri_normals[found.face]).sum(1) > MIN_NORMAL_COS)
            )
            w = ok.astype(float)
            a = sp.diags(w) + RIM_WEIGHT * stl + alpha * ltl
            b = w[:, None] * found.closest + RIM_WEIGHT * srhs + alpha * lx0
            x = spla.splu(a.tocsc()).solve(b)
    found = closest_surface_points(x, surface, outer_tris)
    normals = vertex_normals(x, faces)
    covered_local = (
        np.isin(template.regions[sid], [REGION_NAMES.index(r) for r in COVERED_REGIONS])
        & (found.distance < MAX_DISTANCE_MM)
        & ((normals * tri_normals[found.face]).sum(1) > MIN_NORMAL_COS)
    )
    covered_local[rim_local] = True  # the rims are always ICT's rims
    return Registration(
        rotation=rot,
        translation=trans,
        covered=sid[covered_local],
        triangle=outer[found.face[covered_local]],
        barycentric=found.barycentric[covered_local],
        registered=x,
        distance=found.distance[covered_local],
    )


class Transfer:
    """The linear map from fields on ICT's skin vertices to displacements of the template's vertices
    (module docstring). Built from the template mesh (topology and regions) and a :class:`Registration`'s
    correspondence; ``apply`` is cheap (one sparse product and one factorised solve).

    Args:
        faces: ``(F, 3)`` template faces; regions: ``(V,)`` region ids; vertices: ``(V, 3)`` template mm
            (which skin vertex is nearest to each tooth and tongue vertex); eye_loops: the two eyelid rims
            (left, right).
        covered, triangle, barycentric: the correspondence (:class:`Registration`).
        ict_triangles: ``(T, 3)`` ICT's skin triangles; num_ict: N, ICT's skin vertex count.
    """

    def __init__(self, faces, regions, vertices, eye_loops, covered, triangle, barycentric, ict_triangles, num_ict):
        from scipy.spatial import cKDTree

        v_count = len(regions)
        self.num_vertices = v_count
        self.covered = np.asarray(covered, np.int64)
        corners = np.asarray(ict_triangles)[np.asarray(triangle)]  # (C, 3)
        rows = np.repeat(np.arange(len(self.covered)), 3)
        self._interp = sp.csr_matrix(
            (np.asarray(barycentric, float).ravel(), (rows, corners.ravel())), shape=(len(self.covered), num_ict)
        )
        template = TemplateMesh(
            vertices=np.asarray(vertices, float),
            faces=np.asarray(faces),
            face_uvs=np.zeros((len(faces), 3, 2)),
            regions=np.asarray(regions),
            mirror=np.arange(v_count),
            eye_loops=(np.zeros(0, np.int64), np.zeros(0, np.int64)),
            mouth_loop=np.zeros(0, np.int64),
            translation=np.zeros(3),
            source=np.arange(v_count),
        )
        skin, skin_faces = _pieces(template)
        sid = np.flatnonzero(skin)
        local = np.full(v_count, -1)
        local[sid] = np.arange(len(sid))
        lap = _laplacian(len(sid), local[template.faces[skin_faces]], template.vertices[sid])
        is_cov = np.zeros(len(sid), bool)
        is_cov[local[self.covered]] = True
        self._free = sid[~is_cov]
        self._cov_local = np.flatnonzero(is_cov)
        free_local = np.flatnonzero(~is_cov)
        self._lap_fc = lap[free_local][:, self._cov_local].tocsr()
        self._solve = spla.splu(lap[free_local][:, free_local].tocsc())
        # covered ids in local order (the order of _cov_local) -> rows of _interp
        pos = np.full(v_count, -1)
        pos[self.covered] = np.arange(len(self.covered))
        self._cov_order = pos[sid[self._cov_local]]
        eyeballs = template.regions == REGION_NAMES.index("eyeballs")
        self._eyes = (np.flatnonzero(eyeballs & (vertices[:, 0] > 0)), np.flatnonzero(eyeballs & (vertices[:, 0] < 0)))
        self._eye_loops = tuple(np.asarray(lp, np.int64) for lp in eye_loops)
        # teeth and tongue: connected pieces, each moved by the mean displacement of the skin vertices nearest
        # to its vertices
        self._rigid = []
        other = np.isin(template.regions, [REGION_NAMES.index("teeth"), REGION_NAMES.index("tongue")])
        tree = cKDTree(vertices[sid])
        for piece in _components(np.flatnonzero(other), template.faces):
            _, near = tree.query(vertices[piece])
            self._rigid.append((piece, sid[np.asarray(near).ravel()]))

    def apply(self, field: np.ndarray, eye_centres: np.ndarray | None = None) -> np.ndarray:
        """Displacements ``(..., V, 3)`` of the template's vertices, mm, for ICT fields ``(..., N, 3)`` (already
        in the rig's orientation); the eyeballs move with their rims, or by ``eye_centres`` ``(..., 2, 3)``
        (left, right) where given."""
        field = np.asarray(field, float)
        batch = field.shape[:-2]
        f = np.moveaxis(field.reshape((-1,) + field.shape[-2:]), 0, 1).reshape(field.shape[-2], -1)  # (N, B*3)
        d = self._continue(self._interp @ f, eye_centres, f.shape[1])
        return np.moveaxis(d.reshape(self.num_vertices, -1, 3), 1, 0).reshape(batch + (self.num_vertices, 3))

    def extend(self, covered: np.ndarray, eye_centres: np.ndarray | None = None) -> np.ndarray:
        """``(V, 3)`` displacements from given displacements of the covered vertices ``(C, 3)`` (in
        :attr:`covered` order): the continuation alone (eyeballs as in :meth:`apply`)."""
        return self._continue(np.asarray(covered, float), eye_centres, 3)

    def _continue(self, dc: np.ndarray, eye_centres: np.ndarray, width: int) -> np.ndarray:
        d = np.zeros((self.num_vertices, width))
        d[self.covered] = dc
        d[self._free] = self._solve.solve(-(self._lap_fc @ dc[self._cov_order]))
        if eye_centres is None:
            eyes = np.stack([d[loop].mean(0) for loop in self._eye_loops])
        else:
            eyes = np.moveaxis(np.asarray(eye_centres, float).reshape((-1, 2, 3)), 0, 1).reshape(2, -1)
        for side, ids in enumerate(self._eyes):
            d[ids] = eyes[side]
        for piece, near in self._rigid:
            d[piece] = d[near].mean(0)
        return d


def _components(ids: np.ndarray, faces: np.ndarray) -> list[np.ndarray]:
    """Connected components (by faces) of the vertex set ``ids``, sorted by smallest id."""
    from scipy.sparse.csgraph import connected_components

    if len(ids) == 0:
        return []
    inside = np.zeros(faces.max() + 1, bool)
    inside[ids] = True
    f = faces[inside[faces].all(1)]
    local = np.full(len(inside), -1)
    local[ids] = np.arange(len(ids))
    e = mesh_edges(local[f])
    g = sp.coo_matrix((np.ones(len(e)), (e[:, 0], e[:, 1])), shape=(len(ids), len(ids)))
    _, label = connected_components(g, directed=False)
    return [ids[label == k] for k in np.unique(label)]
