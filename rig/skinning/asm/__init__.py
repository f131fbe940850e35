"""ASM, the Adaptive Skinning Model (Yang et al., ICCV 2023), on the rig's template and 52 joints.

ASM makes every part of a skinning model a fitting variable, so that a head can be registered without
any training data:

- **GMM skinning weights** (ASM eq. 4-6): bone ``j``'s weight field is a ``K``-component 2D Gaussian
  mixture in the template's UV space, ``W_j(u) = sum_k pi_jk N(u | zeta_j + mu_jk, Sigma_jk)``, and a
  vertex's weights are the fields normalised across bones, ``w_vj = W_j(u_v) / sum_i W_i(u_v)``
  (:func:`gmm_skinning_weights`, computed in log space so that vertices far from every Gaussian stay
  finite).
- **Dynamic bone binding** (ASM eq. 7-16, Appendix B): bone ``j``'s bind position is a UV point
  ``zeta_j`` mapped to 3D by barycentric interpolation on the template,
  ``psi_j = alpha v_A + beta v_B + gamma v_C - v_t + psi_j^0`` (:func:`bone_positions_from_uv`), where
  ``t`` is the anchor vertex whose UV is the initial ``zeta_j``. The bind poses are recomputed from
  ``psi`` with the rotation and scale of the initial binding (the identity for this rig), which is
  :func:`rig.lbs.joint_world_transforms` with per-head bind positions.
- **Bone transforms** ``tau_j`` (9 floats: rotation xyz in degrees, translation xyz in mm, scale xyz as
  ``factor - 1``), composed down the joint hierarchy as in JNR.

Per bone that is ``2 + K + 2K + 3K + 9 = 11 + 6K`` floats (ASM Table 1); with the rig's 52 joints and
``K = 2``, 1196.

Our choices where ASM is silent or differs (each is tested):

- **pi**: ASM writes ``sum_k pi_k = 1`` but counts ``K`` floats per bone, and the normalisation across
  bones makes a bone's total mass matter. We keep ``K`` free positive amplitudes, stored as
  ``log_pi``.
- **Sigma**: stored as 3 Cholesky floats ``(log l11, log l22, l21)``, ``Sigma = L L^T``, so it is
  symmetric positive definite for any value (:func:`sigma_from_cholesky`).
- **UV domain.** MakeHuman's atlas has 12 UV islands. The GMM covers the skin island (scalp, face,
  ears, the top of the neck: 3185 vertices). Vertices only on the other islands (the rest of the neck,
  the eye pockets, eyeballs, mouth bag, teeth and tongue: 1689 vertices, which ASM's BFM mesh does not
  have) keep the rig's painted initial weights. The island's 18 **seam** vertices (the back of the
  scalp, where the island is cut) have two UV copies: their mixture value is the mean of the values at
  both copies, so the weights are continuous across the seam and mirror-symmetric. The island is
  mirror-symmetric about the line ``v = c`` (``c`` = 0.4832); per-vertex UVs are symmetrised about it
  (a change of at most 4e-4) so that symmetric GMM parameters give exactly symmetric weights.
- **zeta outside the island**: it is located in the nearest skin triangle and the barycentric
  coordinates extrapolate linearly, so the bone keeps moving smoothly (the regulariser keeps it near).
- **Anchor vertex t** (ASM eq. 5): the skin-island vertex nearest to the bone's initial position in
  3D (ASM projects along z then takes the nearest vertex; many of our joints are inside the head),
  chosen among vertices with one UV; joints on the midline take a midline vertex and right joints
  the mirror of their left partner's, so the binding is symmetric.

Modules: :mod:`~rig.skinning.asm.parameters` (the parameters, their JSON form),
:mod:`~rig.skinning.asm.gmm` (the weights), :mod:`~rig.skinning.asm.binding` (bones in UV space, the skin
island), :mod:`~rig.skinning.asm.initial` (the initial GMM fit and its asset), :mod:`~rig.skinning.asm.model`
(:class:`AdaptiveSkinning`), :mod:`~rig.skinning.asm.fit` (registration). Their public names are
re-exported here.

Frames and units as the rest of :mod:`rig`: millimetres, rig space (+Y up, +Z out of the face, +X the
subject's left), column vectors.
"""

from rig.skinning.asm.binding import (
    SCALE_FLOOR,
    STATIC_REGIONS,
    UvDomain,
    bone_local_transforms,
    bone_positions_from_uv,
    locate_uv,
    mirror_uv,
    uv_barycentric,
    uv_domain,
    uv_face_tree,
)
from rig.skinning.asm.fit import AsmFit, fit_asm
from rig.skinning.asm.gmm import cholesky_from_sigma, gmm_log_density, gmm_skinning_weights, sigma_from_cholesky
from rig.skinning.asm.initial import (
    INIT_COMPONENTS,
    GmmInitFit,
    build_initial_gmm,
    default_init_path,
    fit_initial_gmm,
    load_initial_gmm,
    save_initial_gmm,
    symmetrize_gmm,
)
from rig.skinning.asm.model import LOG_PI_RANGE, SIGMA_RANGE, AdaptiveSkinning
from rig.skinning.asm.parameters import (
    ASM_CHANNELS,
    DEFAULT_COMPONENTS,
    TAU_UNITS,
    UV_UNIT,
    AsmInitError,
    AsmParameters,
    AsmRegularizer,
    AsmVariant,
    asm_params_from_dict,
    asm_params_to_dict,
)

__all__ = [
    "ASM_CHANNELS",
    "DEFAULT_COMPONENTS",
    "INIT_COMPONENTS",
    "LOG_PI_RANGE",
    "SCALE_FLOOR",
    "SIGMA_RANGE",
    "STATIC_REGIONS",
    "TAU_UNITS",
    "UV_UNIT",
    "AdaptiveSkinning",
    "AsmFit",
    "AsmInitError",
    "AsmParameters",
    "AsmRegularizer",
    "AsmVariant",
    "GmmInitFit",
    "UvDomain",
    "asm_params_from_dict",
    "asm_params_to_dict",
    "bone_local_transforms",
    "bone_positions_from_uv",
    "build_initial_gmm",
    "cholesky_from_sigma",
    "default_init_path",
    "fit_asm",
    "fit_initial_gmm",
    "gmm_log_density",
    "gmm_skinning_weights",
    "load_initial_gmm",
    "locate_uv",
    "mirror_uv",
    "save_initial_gmm",
    "sigma_from_cholesky",
    "symmetrize_gmm",
    "uv_barycentric",
    "uv_domain",
    "uv_face_tree",
]
