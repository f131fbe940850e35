"""How well the ICT Face Model transfers onto the template's topology (issue 25).

Three measurements, per region of the template (mm):

1. **Registration of the mean**: for every covered vertex, the distance from the non-rigid ICP's result to
   its point on the ICT mean (how far the final projection moved it), and how many vertices of each region
   are covered (the rest is continued: :mod:`rig.ict.transfer`).
2. **Zero parameters = the ICT mean**: the distance of the committed template's covered vertices to the ICT
   mean's surface in the rig frame (what the mirror symmetrisation costs; plus the storage error of
   :mod:`rig.ict.data`, < 0.001 mm).
3. **Transfer vs direct registration**: ICT identities (the first ``--heads`` of the ``test`` split's
   coefficients) made on the template two ways: transferred (the mean on the template plus the transferred
   modes, :class:`rig.ict.transfer.Transfer`) and registered directly (the whole registration run on that
   head, :func:`rig.ict.mean.on_template`); the vertex-to-vertex distance between the two, per region.
   Both before placement and symmetrisation, in the same frame. Reported two ways: vertex to vertex (this
   includes how far the direct registration lets vertices slide along a smooth surface: the scalp, the neck)
   and vertex to the direct registration's surface (the shape difference; each piece to the same piece).

Also the template's change in shape (MakeHuman's average head -> the ICT mean), per region, vertex to
vertex after the least-squares similarity. ``--figure`` renders the transfer error of the first head on the
template (distance to the direct registration's surface, grey to red, 0 to 1 mm), front and side.

    .venv/bin/python benchmarks/bench_ict_transfer.py [--heads 3] [--out benchmarks/results/ict_transfer.json]
        [--figure docs/ict_transfer.png]
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))

from pipeline.synthetic.population import ict_coefficients, split_seeds  # noqa: E402
from rig.asset import load_asset  # noqa: E402
from rig.geometry import Similarity, closest_surface_points  # noqa: E402
from rig.ict.data import load_ict  # noqa: E402
from rig.ict.mean import on_template  # noqa: E402
from rig.ict.transfer import Transfer  # noqa: E402
from rig.template import REGION_NAMES, build_makehuman_template  # noqa: E402


def per_region(values: np.ndarray, regions: np.ndarray, ids: np.ndarray | None = None) -> dict[str, dict]:
    """``{region: {n, mean, p95, max}}`` of per-vertex values (``ids``: which vertices they belong to)."""
    ids = np.arange(len(regions)) if ids is None else ids
    out = {}
    for k, name in enumerate(REGION_NAMES):
        sel = regions[ids] == k
        if sel.any():
            v = values[sel]
            out[name] = {
                "n": int(sel.sum()),
                "mean": round(float(v.mean()), 4),
                "p95": round(float(np.percentile(v, 95)), 4),
                "max": round(float(v.max()), 4),
            }
    return out


def _piece_faces(base) -> list[tuple[np.ndarray, np.ndarray]]:
    """``(vertex ids, face mask)`` of each piece: the skin (all but eyeballs, teeth, tongue) and each of those."""
    rigid = [REGION_NAMES.index(r) for r in ("eyeballs", "teeth", "tongue")]
    out = []
    for group in ([k for k in range(len(REGION_NAMES)) if k not in rigid], *([k] for k in rigid)):
        inside = np.isin(base.regions, group)
        out.append((np.flatnonzero(inside), inside[base.faces].all(1)))
    return out


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--heads", type=int, default=3)
    parser.add_argument("--out", type=Path, default=ROOT / "benchmarks" / "results" / "ict_transfer.json")
    parser.add_argument("--figure", type=Path)
    args = parser.parse_args()
    t0 = time.perf_counter()
    ict, asset, base = load_ict(), load_asset(), build_makehuman_template()
    mean_raw, reg = on_template(base, ict)
    regions = base.regions
    result: dict = {"command": " ".join(["benchmarks/bench_ict_transfer.py"] + sys.argv[1:])}
    result["registration_distance"] = per_region(reg.distance, regions, reg.covered)
    result["covered"] = {
        name: f"{int((regions[reg.covered] == k).sum())}/{int((regions == k).sum())}"
        for k, name in enumerate(REGION_NAMES)
    }
    surface = ict.neutral @ asset.ict_rotation.T + asset.ict_translation
    found = closest_surface_points(asset.vertices[asset.ict_covered], surface, ict.triangles)
    result["template_to_ict_mean"] = per_region(found.distance, regions, asset.ict_covered)
    sim = Similarity.fit(base.vertices, asset.vertices, with_scale=True)
    change = np.linalg.norm(sim.apply(base.vertices) - asset.vertices, axis=1)
    result["template_change"] = {
        "similarity_scale": round(sim.scale, 4),
        "per_region": per_region(change, regions),
        "rms_all": round(float(np.sqrt((change**2).mean())), 3),
    }
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
    modes = transfer.apply(ict.identity.astype(np.float64) @ reg.rotation.T)
    errors, to_surface = [], []
    for seed in split_seeds("test")[: args.heads]:
        c = ict_coefficients(int(seed))
        transferred = mean_raw + np.tensordot(c, modes, axes=1)
        direct, _ = on_template(base, ict, ict.head(c))
        errors.append(np.linalg.norm(transferred - direct, axis=1))
        to_surface.append(
            np.concatenate(
                [
                    closest_surface_points(transferred[piece], direct, base.faces[mask]).distance
                    for piece, mask in _piece_faces(base)
                ]
            )[np.argsort(np.concatenate([piece for piece, _ in _piece_faces(base)]))]
        )
    err, surf = np.stack(errors), np.stack(to_surface)
    result["transfer_vs_direct"] = {
        "heads": args.heads,
        "per_region": per_region(err.mean(0), regions),
        "to_surface_per_region": per_region(surf.mean(0), regions),
        "to_surface_all_mean": round(float(surf.mean()), 4),
        "to_surface_all_max": round(float(surf.max()), 4),
        "face_mean": round(
            float(
                err[
                    :,
                    np.isin(
                        regions,
                        [
                            REGION_NAMES.index(r)
                            for r in ("forehead", "brows", "eyelids", "nose", "cheeks", "lips", "chin")
                        ],
                    ),
                ].mean()
            ),
            4,
        ),
        "all_mean": round(float(err.mean()), 4),
        "all_max": round(float(err.max()), 4),
    }
    result["seconds"] = round(time.perf_counter() - t0, 1)
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(json.dumps(result, indent=2) + "\n")
    print(json.dumps({k: result[k] for k in ("transfer_vs_direct", "template_change", "seconds")}, indent=1))
    if args.figure:
        from PIL import Image

        from render.preview import render_preview

        hidden = np.isin(regions, [REGION_NAMES.index(r) for r in ("teeth", "tongue", "mouth_interior")])
        faces = base.faces[~hidden[base.faces].any(1)]
        t = np.clip(surf[0] / 1.0, 0, 1)[:, None]
        colours = (1 - t) * np.array([0.6, 0.6, 0.6]) + t * np.array([0.8, 0.05, 0.05])
        tiles = [
            render_preview(
                asset.vertices,
                faces,
                colors=colours,
                view=view,
                size=(360, 440),
                spp=32,
                target=(0.0, -20.0, 0.0),
                distance=800,
            )
            for view in ("front", "side")
        ]
        Image.fromarray(np.concatenate(tiles, 1)).save(args.figure)


if __name__ == "__main__":
    main()
