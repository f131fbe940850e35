"""The accessory on a fitted head: skinning and expression offsets transferred from the fit's own head
(:mod:`rig.accessory`), posed on the fit."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from pipeline.accessory.inputs import Accessory
from pipeline.head.fitted import FittedHead
from rig.accessory import (
    DEFAULT_FALLOFF_MM,
    DEFAULT_SMOOTHING_MM,
    AccessorySkinning,
    channel_reach,
    joint_motion_distance,
    outer_skin_faces,
    pose_accessory,
    signed_distance,
    transfer_skinning,
)
from rig.asset import load_asset
from rig.expressions import morph_targets
from rig.lbs import joint_world_transforms


@dataclass(frozen=True)
class AccessoryOnFit:
    """An accessory transferred to and posed on a fitted head (:func:`accessory_on_fit`).

    Attributes:
        accessory: the input; head: the fit.
        skinning: the transfer (:class:`rig.accessory.AccessorySkinning`, from the fit's weights).
        posed: ``(N, 3)`` the accessory posed on the fit, mm.
        signed_distance: ``(N,)`` of the posed accessory's vertices to the fitted head's outer skin, mm
            (negative: inside).
    """

    accessory: Accessory
    head: FittedHead
    skinning: AccessorySkinning
    posed: np.ndarray
    signed_distance: np.ndarray


def joint_distance(asset) -> np.ndarray:
    """``(J, J)`` mm: :func:`rig.accessory.joint_motion_distance` of the rig's joints (their channels' reach
    at 100 mm), for the transfer's choice of kept influences."""
    return joint_motion_distance(asset.parents, channel_reach(len(asset.joint_names)))


def accessory_on_fit(
    head: FittedHead,
    accessory: Accessory,
    *,
    falloff_mm: float = DEFAULT_FALLOFF_MM,
    smoothing_mm: float = DEFAULT_SMOOTHING_MM,
    asset=None,
) -> AccessoryOnFit:
    """Transfer the fit's skinning to the accessory (:func:`rig.accessory.transfer_skinning` on the template's
    outer skin with the fit's weights and the 52 ARKit shapes) and pose it with the fit's joints and
    expressions (:func:`rig.accessory.pose_accessory`)."""
    import torch

    asset = asset or load_asset()
    skin = outer_skin_faces(asset)
    transfer = transfer_skinning(
        asset.vertices,
        skin,
        head.weights,
        morph_targets(asset),
        accessory.vertices,
        falloff_mm=falloff_mm,
        smoothing_mm=smoothing_mm,
        joint_distance=joint_distance(asset),
    )
    _, transforms = joint_world_transforms(
        torch.as_tensor(head.tau[None], dtype=torch.float64),
        torch.as_tensor(asset.joint_positions, dtype=torch.float64),
        torch.as_tensor(asset.parents, dtype=torch.long),
    )
    with torch.no_grad():
        posed = pose_accessory(
            accessory.vertices, transfer, transforms, torch.as_tensor(head.expressions[None], dtype=torch.float64)
        )[0].numpy()
    distance = signed_distance(posed, head.vertices, skin)
    return AccessoryOnFit(accessory, head, transfer, posed, distance)
