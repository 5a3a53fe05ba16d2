"""Quality numbers: how close a synthesized field's neighbourhoods are to the exemplar's."""

from __future__ import annotations

import numpy as np

__all__ = ["bidirectional_block_distance"]


def bidirectional_block_distance(
    exemplar: np.ndarray,
    output: np.ndarray,
    block: int,
    *,
    samples: int = 200,
    seed: int | None = 0,
    device: str | None = None,
) -> dict:
    """Mean nearest-block distance between two uint8 volumes, both ways.

    For ``samples`` random blocks of the output, the exact nearest block of the
    exemplar; for ``samples`` random blocks of the exemplar, the exact nearest block of
    the output; distances are SSD / block^3 (squared uint8 units per sample).

    Args:
        exemplar, output: (Z, Y, X) uint8 volumes, each at least ``block`` per side.
        block: block size.
        samples: blocks drawn from each side (all of them when fewer exist).
        seed: seed of the Generator that draws them.
        device: device of the gather kernel.

    Returns:
        {"output_to_exemplar": float, "exemplar_to_output": float, "mean": float}.
    """
    from geosynth.backend import to_device
    from geosynth.scoring import score_gather
    from geosynth.selection import argmin
    from geosynth.search import block_offsets

    for name, v in (("exemplar", exemplar), ("output", output)):
        if v.dtype != np.uint8 or v.ndim != 3 or min(v.shape) < block:
            raise ValueError(f"{name} must be a uint8 (Z, Y, X) volume of at least {block} per side, got {v.dtype} {v.shape}.")
    rng = np.random.default_rng(seed)
    off = block_offsets(block)

    def one_way(queries_from: np.ndarray, search_in: np.ndarray) -> float:
        counts = [s - block + 1 for s in queries_from.shape]
        total = int(np.prod(counts))
        picks = rng.choice(total, size=min(samples, total), replace=False)
        grid = to_device(search_in, "auto" if device is None else device)
        dists = []
        for idx in picks:
            z, y, x = np.unravel_index(idx, counts)
            q = queries_from[z:z + block, y:y + block, x:x + block].reshape(-1)
            scores = score_gather(grid, off, q, keep_on_device=True)
            best = argmin(scores)
            dists.append(int(scores.numpy()[best]) / block**3)  # sync: one score per query
        return float(np.mean(dists))

    a = one_way(output, exemplar)
    b = one_way(exemplar, output)
    return {"output_to_exemplar": a, "exemplar_to_output": b, "mean": (a + b) / 2}
