"""Keyframed morph-target weights and joint transforms as one glTF animation (:class:`GltfAnimation`,
``jnr animate``). See :mod:`rig.io.gltf`.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import pygltflib

from rig.errors import InputError, shape_error
from rig.io.gltf.encoding import _FLOAT, _BufferBuilder
from rig.io.gltf.skin import _joint_nodes

__all__ = ["GltfAnimation"]


@dataclass(frozen=True)
class GltfAnimation:
    """Keyframes of a head's morph-target weights and joint transforms, one glTF animation (``LINEAR``).

    Attributes:
        times: ``(T,)`` strictly increasing keyframe times in seconds, ``T >= 1``.
        morph_weights: ``(T, M)`` weights of the ``M`` morph targets per keyframe (every mesh node with
            targets gets a ``weights`` channel); None: no morph channel.
        joint_transforms: ``(T, K, 4, 4)`` each joint's local pose transform ``tau_k`` per keyframe, as
            ``joint_transforms`` of :func:`export_skinned_gltf` (millimetres; translation @ rotation @
            positive scale); channels are written only for the joints and paths
            (translation/rotation/scale) that change over time. None: no joint channels.
        name: the animation's name.
    """

    times: np.ndarray
    morph_weights: np.ndarray | None = None
    joint_transforms: np.ndarray | None = None
    name: str = "animation"


def _joint_trs_keys(
    func: str, taus: np.ndarray, names: list[str], par: np.ndarray, pos: np.ndarray
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Node TRS of every joint per keyframe: translations ``(T, K, 3)`` m, rotations ``(T, K, 4)`` xyzw with
    consecutive keys in one hemisphere, scales ``(T, K, 3)``."""
    n_keys, k = taus.shape[:2]
    trans, rots, scales = np.zeros((n_keys, k, 3)), np.zeros((n_keys, k, 4)), np.zeros((n_keys, k, 3))
    for t in range(n_keys):
        nodes, _ = _joint_nodes(f"{func}: animation keyframe {t}", names, par, pos, taus[t])
        for j, node in enumerate(nodes):
            trans[t, j] = node.translation
            rots[t, j] = node.rotation or (0.0, 0.0, 0.0, 1.0)
            scales[t, j] = node.scale or (1.0, 1.0, 1.0)
    for t in range(1, n_keys):  # LINEAR quaternion keys interpolate along the short arc only within a hemisphere
        flip = np.sum(rots[t] * rots[t - 1], axis=1) < 0.0
        rots[t, flip] *= -1.0
    return trans, rots, scales


def _add_animation(
    func: str,
    gltf: pygltflib.GLTF2,
    builder: _BufferBuilder,
    animation: GltfAnimation,
    names: list[str],
    par: np.ndarray,
    pos: np.ndarray,
    n_targets: int,
    morph_nodes: list[int],
) -> None:
    """Append ``animation`` to ``gltf`` (its accessors to ``builder``): one shared time accessor, a channel per
    animated joint path and per mesh node with morph targets."""
    if not isinstance(animation, GltfAnimation):
        raise InputError(f"{func}: animation must be a GltfAnimation, got {type(animation).__name__}")
    times = np.asarray(animation.times, dtype=np.float64).reshape(-1)
    if times.size == 0 or not np.isfinite(times).all() or np.any(np.diff(times) <= 0.0) or times[0] < 0.0:
        raise InputError(f"{func}: animation times must be finite, >= 0 and strictly increasing (T >= 1)")
    n_keys = times.size
    samplers: list[pygltflib.AnimationSampler] = []
    channels: list[pygltflib.AnimationChannel] = []
    time_accessor = None

    def channel(node: int, path: str, values: np.ndarray, accessor_type: str) -> None:
        nonlocal time_accessor
        if time_accessor is None:
            time_accessor = builder.add(times.astype(np.float32), _FLOAT, "SCALAR", min_max=True, name="time")
        out = builder.add(values, _FLOAT, accessor_type, name=f"{path}_{node}")
        samplers.append(pygltflib.AnimationSampler(input=time_accessor, output=out, interpolation="LINEAR"))
        channels.append(
            pygltflib.AnimationChannel(
                sampler=len(samplers) - 1, target=pygltflib.AnimationChannelTarget(node=node, path=path)
            )
        )

    if animation.joint_transforms is not None:
        taus = np.asarray(animation.joint_transforms, dtype=np.float64)
        if taus.shape != (n_keys, len(names), 4, 4):
            raise shape_error(
                func, "animation.joint_transforms", f"(T, K, 4, 4) = ({n_keys}, {len(names)}, 4, 4)", taus.shape
            )
        if not np.isfinite(taus).all():
            raise InputError(f"{func}: animation.joint_transforms contain NaN or infinite values")
        trans, rots, scales = _joint_trs_keys(func, taus, names, par, pos)
        for j in range(len(names)):
            for path, values, kind in (
                ("translation", trans[:, j], "VEC3"),
                ("rotation", rots[:, j], "VEC4"),
                ("scale", scales[:, j], "VEC3"),
            ):
                if np.ptp(values, axis=0).max() > 1e-9:
                    channel(j, path, values, kind)
    if animation.morph_weights is not None:
        w = np.asarray(animation.morph_weights, dtype=np.float64)
        if w.shape != (n_keys, n_targets) or n_targets == 0:
            raise shape_error(func, "animation.morph_weights", f"(T, M) = ({n_keys}, {n_targets})", w.shape)
        if not np.isfinite(w).all():
            raise InputError(f"{func}: animation.morph_weights contain NaN or infinite values")
        for node in morph_nodes:
            channel(node, "weights", w.reshape(-1), "SCALAR")
    if not channels:
        raise InputError(f"{func}: the animation animates nothing (no morph weights, no joint transform changes)")
    gltf.animations = [pygltflib.Animation(name=animation.name, samplers=samplers, channels=channels)]
