"""The photometric stages of a photo fit: the light's initial fit, the appearance (albedo, light) and
the objective that compares the rendered head with the photo in the face crop."""

from __future__ import annotations

import math

import numpy as np
import torch

from pipeline.fitting.engine import Loss, Stage, StageLog, run_schedule
from pipeline.fitting.priors import cached_identity_prior
from pipeline.fitting.state import GEOMETRY_GROUPS, PhotoState
from pipeline.fitting.terms import L2, Charbonnier, Inputs, Term, term_values
from pipeline.photo.crop import Crop, face_crop
from pipeline.photo.fit_config import PhotometricConfig
from pipeline.photo.landmark_fit import (
    LandmarkTerm,
)
from pipeline.photo.sh import fit_sh, sh_basis
from render.backend import reproducible
from render.lighting import Lighting
from render.renderer import DifferentiableRenderer
from rig.errors import InputError
from rig.geometry import mesh_edges, vertex_normals
from rig.optim import Progress, torch_threads


def hemisphere_directions(n: int) -> np.ndarray:
    """``(n, 3)`` light travel directions (camera frame, OpenCV) spread over the cap ``z >= 0.25``: light
    coming from the camera's side of the face."""
    i = np.arange(n) + 0.5
    z = 1.0 - (1.0 - 0.25) * i / n
    phi = i * math.pi * (3.0 - math.sqrt(5.0))
    r = np.sqrt(1.0 - z * z)
    return np.stack([r * np.cos(phi), r * np.sin(phi), z], 1)


def fit_light(
    albedo_img: np.ndarray, normals: np.ndarray, target: np.ndarray, directions: np.ndarray
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Per-pixel ``target ~ albedo (ambient + irradiance / pi * max(0, n . -d))``: the best ``d`` of
    ``directions`` and its non-negative ambient/irradiance (linear least squares per channel).

    Args: albedo_img, target ``(N, 3)``; normals ``(N, 3)``; directions ``(D, 3)``.
    Returns: ``(direction (3,), ambient (3,), irradiance (3,))``.
    """
    cos = np.clip(-(normals @ directions.T), 0.0, None) / math.pi  # (N, D)
    best = (math.inf, directions[0], np.full(3, 0.5), np.zeros(3))
    for k in range(len(directions)):
        err, amb, irr = 0.0, np.zeros(3), np.zeros(3)
        for c in range(3):
            a = albedo_img[:, c]
            design = np.stack([a, a * cos[:, k]], 1)
            sol, *_ = np.linalg.lstsq(design, target[:, c], rcond=None)
            sol = np.clip(sol, 0.0, None)
            err += float(np.square(design @ sol - target[:, c]).sum())
            amb[c], irr[c] = sol
        if err < best[0]:
            best = (err, directions[k], amb, irr)
    return best[1], best[2], best[3]


def fit_appearance(
    photo: np.ndarray,
    lm: np.ndarray,
    focal: float,
    state: PhotoState,
    term: LandmarkTerm,
    settings: PhotometricConfig,
    progress: Progress | None,
    noise_px: float,
) -> tuple[dict[str, np.ndarray], tuple[StageLog, ...], Crop | None]:
    """The photometric stages when enabled (updating ``state``): ``({albedo, ambient, irradiance,
    light_camera}, stage logs, crop)``; ``noise_px``: the landmarks' error (the landmark term is divided by its
    square, as in the landmark fit: :meth:`~pipeline.photo.landmark_fit.LandmarkFitConfig.noise_for`). Without
    them nothing of the appearance is fitted: a grey albedo and a key light from the camera's upper left
    (travelling right, down and forward) + fill, so that render.png and overlay.png show the fitted shape shaded
    rather than flat."""
    if not (settings.enabled and any(s.iterations > 0 for s in settings.stages)):
        light = np.array([0.3, 0.4, 1.0]) / np.linalg.norm([0.3, 0.4, 1.0])
        grey = np.full((len(term.asset.vertices), 3), 0.5)
        shown = {"albedo": grey, "ambient": np.full(3, 0.35), "irradiance": np.full(3, 2.0), "light_camera": light}
        return shown, (), None
    crop = face_crop(lm, settings.render_size, settings.crop_margin)
    light, stages = _photometric(photo, crop, focal, state, term, settings, progress, noise_px)
    appearance = {
        "albedo": state.albedo.detach().double().numpy(),
        "ambient": state.ambient.detach().double().numpy(),
        "irradiance": state.irradiance.detach().double().numpy(),
        "light_camera": light,
    }
    return appearance, stages, crop


def _photometric(
    photo: np.ndarray,
    crop: Crop,
    focal: float,
    state: PhotoState,
    term: LandmarkTerm,
    settings: PhotometricConfig,
    progress: Progress | None,
    noise_px: float,
):
    """The photometric stages; updates ``state`` in place. Returns the light direction (camera frame)
    and the stage logs."""
    # torch's CPU scatter-adds (index backward) are order-dependent on several threads too
    with torch_threads(1 if settings.reproducible else None), reproducible(settings.reproducible):
        fit = PhotometricObjective(photo, crop, focal, state, term, settings, noise_px)
        start = state.theta_n.detach().clone()
        stages = run_schedule(
            state,
            settings.stages,
            fit,
            settings.lr,
            label="fit_photo",
            progress=progress,
            before_stage=fit.before_stage,
        )
        keep_step(state, start, settings.identity_step)
        return np.asarray(fit.direction, float), stages


def keep_step(state: PhotoState, start: torch.Tensor, fraction: float) -> None:
    """Set the joint channels over their span (``state.theta_n``, in place, the identity subspace's step folded in)
    to ``start + fraction * (now - start)``: keep that fraction of what the photometric stages changed
    (:attr:`PhotometricConfig.identity_step`); ``start (P,)`` the channels before them."""
    with torch.no_grad():
        state.theta_n.copy_(start + fraction * (state.joints_n() - start))
        state.identity_c.zero_()


class PhotometricObjective:
    """The loss of the photometric stages (module docstring) and what is re-picked before each stage.

    Builds the renderer of the crop, starts the albedo from the median face colour seen from the
    landmark fit's pose and adds the appearance parameters to ``state``
    (:meth:`~pipeline.fitting.state.PhotoState.add_appearance`) and, when a stage frees ``identity``, the identity
    prior's ``settings.identity_components`` main directions
    (:meth:`~pipeline.fitting.rig_state.FitState.set_identity_subspace`).
    """

    def __init__(
        self,
        photo: np.ndarray,
        crop: Crop,
        focal: float,
        state: PhotoState,
        term: LandmarkTerm,
        settings: PhotometricConfig,
        noise_px: float,
    ) -> None:
        self.state, self.term, self.settings = state, term, settings
        asset = state.rig.asset
        height, width = photo.shape[:2]
        dtype = self.dtype = torch.float32
        target_np, inside_np = crop.cut(photo)
        self.target = torch.as_tensor(target_np, dtype=dtype)
        self.inside = torch.as_tensor(inside_np, dtype=dtype)
        self.face_region_ids = torch.as_tensor([asset.region_names.index(r) for r in settings.face_regions])
        with torch.no_grad():
            v_cam0 = state.to_camera(state.rig_vertices()).to(dtype)
        n_vertices = len(asset.vertices)
        self.renderer = DifferentiableRenderer(
            v_cam0,
            asset.faces,
            torch.full((n_vertices, 3), 0.5),
            crop.camera(focal, width, height, dtype=dtype),
            Lighting(torch.full((3,), 1.0), torch.zeros(3), torch.tensor([0.0, 0.0, 1.0])),
            spp=settings.spp,
            spp_primary=settings.spp_silhouette,
            seed=settings.seed,
            regions=asset.regions,
        )
        # start colour: the median of the face pixels seen from the landmark fit's pose
        with torch.no_grad():
            first = self.renderer.render(v_cam0, torch.full((n_vertices, 3), 0.5), aovs=True)
            m = self.face_mask(first.region_ids) > 0
            if int(m.sum()) < 50:
                raise InputError(
                    f"fit_photo: the face covers only {int(m.sum())} pixels of the "
                    f"{crop.size}x{crop.size} crop; the landmarks do not match the head"
                )
            self.start_colour = self.target[m].median(0).values.clamp(0.02, 0.98)
        state.add_appearance(
            self.start_colour.repeat(n_vertices, 1), torch.full((3,), 1.0, dtype=dtype), torch.zeros(3, dtype=dtype)
        )
        if any("identity" in s.free for s in settings.stages):
            state.set_identity_subspace(cached_identity_prior(), settings.identity_components)
        self.direction = np.array([0.0, 0.0, 1.0])
        self.faces = torch.as_tensor(np.asarray(asset.faces, np.int64))
        self.edges = torch.as_tensor(mesh_edges(asset.faces))
        self.mirror = torch.as_tensor(np.asarray(asset.mirror, np.int64))
        self.candidates = hemisphere_directions(settings.light_directions)
        self.inlier: torch.Tensor | None = None
        self.stages_started = 0
        self.terms = (
            self.photo_term(),
            term.term(settings.lambda_landmarks / noise_px**2, name="landmarks"),
            *state.prior_terms(settings.prior),
            *self.albedo_prior_terms(),
        )

    def face_mask(self, region_ids: torch.Tensor) -> torch.Tensor:
        """``(S, S)`` 1 on face-region pixels inside the photo."""
        return torch.isin(region_ids, self.face_region_ids).to(self.dtype) * self.inside

    def light(self):
        if self.settings.light_model == "sh":  # the shading is in the albedo: the renderer only emits it
            return Lighting(
                torch.ones(3, dtype=self.dtype),
                torch.zeros(3, dtype=self.dtype),
                torch.as_tensor(self.direction, dtype=self.dtype),
            )
        return Lighting(self.state.ambient, self.state.irradiance, torch.as_tensor(self.direction, dtype=self.dtype))

    def shaded_albedo(self, v_cam: torch.Tensor, albedo: torch.Tensor) -> torch.Tensor:
        """``(V, 3)`` what the renderer is given as albedo: the albedo itself (directional light), or the albedo
        times the SH irradiance of each vertex normal (``sh``; differentiable in vertices, albedo and light)."""
        if self.settings.light_model != "sh":
            return albedo
        irradiance = sh_basis(vertex_normals(v_cam, self.faces)) @ self.state.sh.to(v_cam.dtype)
        return albedo * irradiance.clamp_min(0.0)

    def residual_norm(self, image: torch.Tensor) -> torch.Tensor:
        return (image - self.target).square().sum(-1)

    def before_stage(self, stage: Stage) -> dict:
        """Re-pick the light direction (and, before the first stage, its ambient and irradiance) and the
        outlier pixels from the current state."""
        state, dtype = self.state, self.dtype
        with torch.no_grad():
            v_cam = state.to_camera(state.rig_vertices()).to(dtype)
            albedo = state.albedo.clamp(0, 1)
            flat = self.renderer.render(
                v_cam,
                albedo,
                Lighting(torch.ones(3), torch.zeros(3), torch.as_tensor(self.direction, dtype=dtype)),
                aovs=True,
            )
            m = self.face_mask(flat.region_ids) > 0
            if self.settings.light_model == "sh":
                state.sh.copy_(
                    torch.as_tensor(
                        fit_sh(
                            flat.image[m].double().numpy(),
                            flat.normals[m].double().numpy(),
                            self.target[m].double().numpy(),
                            self.settings.sh_ridge,
                        ),
                        dtype=dtype,
                    )
                )
            else:
                self.direction, amb, irr = fit_light(
                    flat.image[m].double().numpy(),
                    flat.normals[m].double().numpy(),
                    self.target[m].double().numpy(),
                    self.candidates,
                )
                if self.stages_started == 0:
                    state.ambient.copy_(torch.as_tensor(amb, dtype=dtype))
                    state.irradiance.copy_(torch.as_tensor(irr, dtype=dtype))
            self.stages_started += 1
            shaded = self.renderer.render(v_cam, self.shaded_albedo(v_cam, albedo), self.light(), aovs=True)
            m = self.face_mask(shaded.region_ids) > 0
            e = self.residual_norm(shaded.image).sqrt()
            med = e[m].median()
            mad = (e[m] - med).abs().median()
            threshold = float(med + self.settings.outlier_mads * 1.4826 * mad)
            self.inlier = (e <= max(threshold, 0.05)).to(dtype)
            outlier_fraction = float(1.0 - self.inlier[m].mean()) if bool(m.any()) else 0.0
        return {"outlier_fraction": outlier_fraction, "light_direction_camera": tuple(float(x) for x in self.direction)}

    def photo_term(self) -> Term:
        """``photo``: ``lambda_photo`` times the mean Charbonnier distance of the linear-RGB residual over the
        inlier face pixels (inputs ``image (B, S, S, 3)``, ``pixel_weights (S * S,)``)."""
        s, target = self.settings, self.target  # not ``self``: a term holding its objective is a reference cycle

        def residual(p: Inputs) -> torch.Tensor:
            image = p["image"]
            return (image - target).reshape(image.shape[0], -1, 3)

        return Term(
            "photo",
            s.lambda_photo,
            residual,
            Charbonnier(s.charbonnier_eps),
            normaliser="weights",
            group_weights="pixel_weights",
            min_normaliser=1.0,
        )

    def albedo_prior_terms(self) -> tuple[Term, ...]:
        """``albedo_smooth``, ``albedo_symmetry``, ``albedo_mean``: mean squared differences of the albedo
        (input ``albedo (V, 3)``, the parameter itself: each term reads it as the optimiser sees it) along mesh
        edges, to the mirror vertex and to the start colour."""
        w, edges, mirror, start = self.settings.albedo_prior, self.edges, self.mirror, self.start_colour

        def along_edges(p: Inputs) -> torch.Tensor:
            return (p["albedo"][edges[:, 0]] - p["albedo"][edges[:, 1]])[None]

        def to_mirror(p: Inputs) -> torch.Tensor:
            return (p["albedo"] - p["albedo"][mirror])[None]

        def to_start(p: Inputs) -> torch.Tensor:
            return (p["albedo"] - start)[None]

        return (
            Term("albedo_smooth", w.smooth, along_edges, L2(), normaliser="mean"),
            Term("albedo_symmetry", w.symmetry, to_mirror, L2(), normaliser="mean"),
            Term("albedo_mean", w.mean, to_start, L2(), normaliser="mean"),
        )

    def __call__(self, free: tuple[str, ...]) -> Loss:
        """One step's loss: render -> Charbonnier over the inlier face pixels, landmarks, priors."""
        state = self.state
        geometry = tuple(g for g in free if g in GEOMETRY_GROUPS)
        v = state.rig_vertices(geometry)
        v_cam = state.to_camera(v, geometry).to(self.dtype)
        out = self.renderer.render(v_cam, self.shaded_albedo(v_cam, state.albedo), self.light(), aovs=True)
        weight = self.face_mask(out.region_ids) * self.inlier
        inputs = state.term_inputs().add(
            {"image": out.image[None], "pixel_weights": weight.reshape(-1)},
            landmarks_px=lambda: self.term.pixels(state, v, geometry),
            albedo=lambda: state.albedo,
        )
        unweighted: dict[str, torch.Tensor] = {}
        terms = term_values(self.terms, inputs, unweighted)
        metrics = {"photo": unweighted["photo"], "landmarks_px2": unweighted["landmarks"], "pixels": int(weight.sum())}
        return Loss(terms, metrics)
