"""The template's shape from the ICT mean: MakeHuman's topology registered to ICT's mean head
(:func:`rig.ict.transfer.register`), its vertices moved onto it, the joints re-placed (:func:`ict_template`).

1. Covered vertices (:data:`rig.ict.transfer.COVERED_REGIONS`) go to their point on the ICT mean; the rest of
   the skin follows by the harmonic continuation of those displacements, the eyeballs with their eyelid rims,
   the teeth and the tongue with the skin nearest them (:class:`rig.ict.transfer.Transfer`).
2. Made exactly mirror-symmetric (ICT's mean is symmetric to ~0.01 mm; the correspondence nearly so) and
   placed by the template's rule (eyeball centres at ``y = 5, z = 58`` mm: :func:`rig.template.placement`).
3. Joints: each joint of :data:`rig.joints.JOINTS` (bind positions on MakeHuman's shape) moves by the mean
   displacement of the vertices it binds, weighted by its initial weights on MakeHuman's shape
   (:func:`rig.skinning.initial.initial_weights`); a joint that binds no vertex (the root, the bones of the
   hierarchy) by its nearest 64 skin vertices' mean displacement, weighted ``1 / d``.
   The initial weights stay MakeHuman's (painted by region and topology, so they carry over).

Units: mm, rig frame.
"""

from __future__ import annotations

import functools
from dataclasses import dataclass

import numpy as np

from rig.ict.data import IctModel, load_ict
from rig.ict.transfer import Registration, Transfer, register
from rig.joints import JOINTS
from rig.template import REGION_NAMES, TemplateMesh, build_makehuman_template, placement

__all__ = ["IctTemplate", "ict_template", "on_template", "replace_joints"]


@dataclass(frozen=True)
class IctTemplate:
    """The template with the ICT mean's shape.

    Attributes:
        mesh: the template (MakeHuman topology, regions and rims; vertices on the ICT mean, placed), mm.
        makehuman: the MakeHuman-shaped template it was made from.
        joint_positions: ``(K, 3)`` re-placed bind positions, mm.
        weights: ``(V, K)`` initial weights (painted on MakeHuman's shape).
        rotation, translation: ICT's frame -> the rig frame: ``x_rig = rotation @ x_ict + translation`` (mm).
        registration: the registration (:class:`rig.ict.transfer.Registration`, before placement).
    """

    mesh: TemplateMesh
    makehuman: TemplateMesh
    joint_positions: np.ndarray
    weights: np.ndarray
    rotation: np.ndarray
    translation: np.ndarray
    registration: Registration


def replace_joints(
    positions: np.ndarray, old: np.ndarray, new: np.ndarray, weights: np.ndarray, skin: np.ndarray
) -> np.ndarray:
    """Joint bind positions ``(K, 3)`` moved with the mesh (module docstring, step 3).

    Args:
        positions: ``(K, 3)`` on ``old``; old, new: ``(V, 3)`` vertices, mm; weights: ``(V, K)``;
        skin: ``(V,)`` bool, the vertices a joint without weights follows.
    """
    d = new - old
    out = np.array(positions, float)
    sid = np.flatnonzero(skin)
    for j in range(len(out)):
        w = weights[:, j]
        if w.sum() > 0:
            out[j] += w @ d / w.sum()
        else:
            dist = np.linalg.norm(old[sid] - positions[j], axis=1)
            near = np.argsort(dist, kind="stable")[:64]
            k = 1.0 / np.maximum(dist[near], 1e-6)
            out[j] += k @ d[sid[near]] / k.sum()
    return out


def ict_template(ict: IctModel | None = None) -> IctTemplate:
    """The template with the ICT mean's shape (module docstring); deterministic. Cached for the default
    model (the registration takes seconds: ``docs/rig.md``)."""
    if ict is None:
        return _default()
    return _build(ict)


@functools.cache
def _default() -> IctTemplate:
    return _build(load_ict())


def on_template(base: TemplateMesh, ict: IctModel, target: np.ndarray | None = None) -> tuple[np.ndarray, Registration]:
    """An ICT head on the template's topology by registration (step 1 of the module docstring): ``(V, 3)``
    mm, rig frame before placement (not symmetrised), and the registration.

    Args:
        base: the MakeHuman-shaped template (:func:`rig.template.build_makehuman_template`).
        ict: the ICT model; target: ``(N, 3)`` the head, ICT's frame, mm (default: the mean).
    """
    reg = register(base, ict, target)
    transfer = Transfer(
        base.faces,
        base.regions,
        base.vertices,
        base.eye_loops,
        reg.covered,
        reg.triangle,
        reg.barycentric,
        ict.triangles,
        len(ict.neutral),
    )
    head = ict.neutral if target is None else np.asarray(target, float)
    surface = head @ reg.rotation.T + reg.translation
    points = (surface[ict.triangles[reg.triangle]] * reg.barycentric[:, :, None]).sum(1)
    return base.vertices + transfer.extend(points - base.vertices[reg.covered]), reg


def _build(ict: IctModel) -> IctTemplate:
    from rig.skinning.initial import initial_weights

    base = build_makehuman_template()
    v, reg = on_template(base, ict)
    eyeballs = base.regions == REGION_NAMES.index("eyeballs")
    m = base.mirror
    v = 0.5 * (v + v[m] * np.array([-1.0, 1.0, 1.0]))
    v[m == np.arange(len(v)), 0] = 0.0
    shift = placement(v, eyeballs)
    v = v + shift
    weights = initial_weights(base)
    skin = ~np.isin(base.regions, [REGION_NAMES.index(r) for r in ("eyeballs", "teeth", "tongue")])
    joints = replace_joints(np.array([j.position for j in JOINTS], float), base.vertices, v, weights, skin)
    mesh = TemplateMesh(
        vertices=v,
        faces=base.faces,
        face_uvs=base.face_uvs,
        regions=base.regions,
        mirror=base.mirror,
        eye_loops=base.eye_loops,
        mouth_loop=base.mouth_loop,
        translation=base.translation + shift,
        source=base.source,
    )
    return IctTemplate(
        mesh=mesh,
        makehuman=base,
        joint_positions=joints,
        weights=weights,
        rotation=reg.rotation,
        translation=reg.translation + shift,
        registration=reg,
    )
