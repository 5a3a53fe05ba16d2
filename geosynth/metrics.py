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
    from geosynth.search import CascadeSearch

    for name, v in (("exemplar", exemplar), ("output", output)):
        if v.dtype != np.uint8 or v.ndim != 3 or min(v.shape) < block:
            raise ValueError(f"{name} must be a uint8 (Z, Y, X) volume of at least {block} per side, got {v.dtype} {v.shape}.")
    rng = np.random.default_rng(seed)

    def one_way(queries_from: np.ndarray, search_in: np.ndarray) -> float:
        counts = [s - block + 1 for s in queries_from.shape]
        total = int(np.prod(counts))
        picks = rng.choice(total, size=min(samples, total), replace=False)
        search = CascadeSearch(search_in, block, device=device)  # exact nearest block
        dists = []
        for idx in picks:
            z, y, x = np.unravel_index(idx, counts)
            _, ssd = search.nearest(queries_from[z:z + block, y:y + block, x:x + block])
            dists.append(ssd / block**3)
        return float(np.mean(dists))

    a = one_way(output, exemplar)
    b = one_way(exemplar, output)
    return {"output_to_exemplar": a, "exemplar_to_output": b, "mean": (a + b) / 2}
