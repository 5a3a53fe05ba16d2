"""The M1 exemplars of issue #32, rebuilt with trimesh (boxes, icospheres, tori and annuli
concatenated, not unioned): rivets.ply, tori.ply, washers.ply in the folder given.

    .venv/bin/python bench/issue32_m1_cases.py /tmp/cases
    geosynth volume /tmp/cases/washers.ply -o out.ply --size 96 --device opencl --seed 1 --png out.png
"""

import geosynth  # noqa: F401,I001  first: it keeps NumPy off its AVX-512 code (geosynth.core.config)
import sys
from pathlib import Path

import numpy as np
import trimesh


def main(folder: str) -> None:
    out = Path(folder)
    out.mkdir(parents=True, exist_ok=True)
    rng = np.random.default_rng(0)
    parts = [trimesh.creation.box(extents=(4, 4, 0.3))]  # plate 4 x 4 x 0.3, 25 rivets r 0.12-0.2
    for i in range(5):
        for j in range(5):
            s = trimesh.creation.icosphere(subdivisions=3, radius=rng.uniform(0.12, 0.2))
            c = np.array([-1.6 + 0.8 * i, -1.6 + 0.8 * j]) + rng.uniform(-0.15, 0.15, 2)
            s.apply_translation([c[0], c[1], 0.15])
            parts.append(s)
    trimesh.util.concatenate(parts).export(out / "rivets.ply")
    parts = []  # 16 tori R 0.45 r 0.09, tilted +-0.6 rad, 0.7 x 0.55 apart (neighbours along y touch)
    for i in range(4):
        for j in range(4):
            t = trimesh.creation.torus(major_radius=0.45, minor_radius=0.09)
            t.apply_transform(trimesh.transformations.rotation_matrix(0.6 if (i + j) % 2 else -0.6, [1, 0, 0]))
            t.apply_translation([0.7 * i, 0.55 * j, 0])
            parts.append(t)
    trimesh.util.concatenate(parts).export(out / "tori.ply")
    parts = []  # one layer of 25 washers r 0.15-0.3, 0.08 thick, jittered 0.8 grid
    for i in range(5):
        for j in range(5):
            w = trimesh.creation.annulus(r_min=0.15, r_max=0.3, height=0.08)
            w.apply_translation([0.8 * i + rng.uniform(-0.1, 0.1), 0.8 * j + rng.uniform(-0.1, 0.1), 0])
            parts.append(w)
    trimesh.util.concatenate(parts).export(out / "washers.ply")


if __name__ == "__main__":
    if any(a.startswith("-") for a in sys.argv[1:]):  # not a folder named "--help"
        sys.exit("usage: python bench/issue32_m1_cases.py [FOLDER]: the cases' meshes in FOLDER (bench/out/issue32_m1)")
    main(sys.argv[1] if len(sys.argv) > 1 else "bench/out/issue32_m1")
