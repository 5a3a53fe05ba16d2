"""The lattice of a periodic slab exemplar (geosynth.volume.lattice) and the scan that
follows it (issue #32: linked rings close across stitches)."""

import numpy as np
import pytest

from conftest import ONE_DEVICE
from geosynth.volume.lattice import find_lattice, lattice_origins
from geosynth.volume.synthesis import is_network, quantize_field, synthesize_volume

# a slanted lattice a fraction of a sample off whole vectors: (dy, dx) samples
TRUE = np.array([[11.3, 2.4], [-3.1, 13.7]])
BAND = 4.0


def _periodic_slab(vectors=TRUE, shape=(8, 60, 64), radius=3.2) -> np.ndarray:
    """Float distances (samples) to balls on the lattice, centred in a slab's thickness:
    exactly periodic across the footprint."""
    z, y, x = np.meshgrid(*(np.arange(n, dtype=np.float64) for n in shape), indexing="ij")
    best = np.full(shape, np.inf)
    for i in range(-8, 9):
        for j in range(-8, 9):
            cy, cx = i * vectors[0] + j * vectors[1] + np.array([5.0, 7.0])
            if -10 < cy < shape[1] + 10 and -10 < cx < shape[2] + 10:
                d = np.sqrt((z - shape[0] / 2) ** 2 + (y - cy) ** 2 + (x - cx) ** 2) - radius
                best = np.minimum(best, d)
    return best.astype(np.float32)


def _same_lattice(found: np.ndarray, true: np.ndarray, tolerance: float) -> bool:
    """Whether each found vector is an integer combination of the true ones (within
    ``tolerance`` samples) and both span cells of the same area."""
    inv = np.linalg.inv(true.T)
    for v in found:
        c = inv @ v
        if np.abs(c - np.round(c)).max() * np.abs(true).max() > tolerance:
            return False
    return abs(abs(np.linalg.det(found)) - abs(np.linalg.det(true))) < 0.05 * abs(np.linalg.det(true))


def test_find_lattice_measures_a_lattice_to_a_fraction_of_a_sample():
    src = quantize_field(_periodic_slab(), BAND)
    found = find_lattice(src, BAND)
    assert found is not None
    assert _same_lattice(found.vectors, TRUE, 0.25), found.vectors
    assert max(found.difference) < 0.1


def test_find_lattice_finds_none_in_an_aperiodic_field(rng):
    from scipy.ndimage import gaussian_filter

    noise = gaussian_filter(rng.standard_normal((8, 64, 64)), (1, 3, 3), mode="wrap")
    src = quantize_field((noise / noise.std() * 3).astype(np.float32), BAND)
    assert find_lattice(src, BAND) is None


def test_lattice_origins_are_congruent_and_inside():
    last = np.array([40, 45])
    for position in [(0, 0), (17, 93), (250, 31)]:
        origins = lattice_origins(position, TRUE, last)
        assert len(origins) >= 2
        assert (origins >= 0).all() and (origins <= last).all()
        for o in origins:
            c = np.linalg.solve(TRUE.T, o - np.array(position, float))
            offset = o - (np.array(position) + np.round(c) @ TRUE)
            assert np.abs(offset).max() <= 0.5 + 1e-9


@pytest.fixture(scope="module")
def lattice_runs():
    return {}


def test_the_scan_copies_only_congruent_samples_and_gives_the_same_bytes_everywhere(device, lattice_runs):
    """Every output column is the source's column at a position congruent to it (the scan
    pasted lattice translates only), and each device gives the same bytes."""
    field = _periodic_slab()
    vol = synthesize_volume(field, (8, 96, 96), levels=2, block=16, seed=3, device=device, progress=False,
                            band=BAND, method="graphcut", lattice=True)
    assert vol.slab and vol.lattice is not None
    assert "lattice" in vol.levels[-1].search
    src, out, vectors = vol.source, vol.quantized, vol.lattice.vectors
    last = np.array(src.shape[1:]) - 1
    for y in range(0, 96, 5):
        for x in range(0, 96, 5):
            cands = lattice_origins((y, x), vectors, last)
            assert any((src[:, oy, ox] == out[:, y, x]).all() for oy, ox in cands), (y, x)
    lattice_runs.setdefault("first", (device, out.tobytes()))
    assert out.tobytes() == lattice_runs["first"][1], f"{device} differs from {lattice_runs['first'][0]}"


def test_lattice_false_keeps_the_free_search():
    vol = synthesize_volume(_periodic_slab(), (8, 64, 64), levels=1, block=16, seed=3, device=ONE_DEVICE,
                            progress=False, band=BAND, method="graphcut", lattice=False)
    assert vol.lattice is None and vol.lattice_text == ""
    with pytest.raises(TypeError, match="lattice"):
        synthesize_volume(_periodic_slab(), (8, 64, 64), levels=1, block=16, device=ONE_DEVICE, progress=False,
                          lattice="yes")


def test_is_network_tells_linked_rings_from_separate_ones_and_a_relief():
    from geosynth.volume.examples import exemplar_field

    assert is_network(exemplar_field("chainmail", 48, device=ONE_DEVICE).values)
    assert not is_network(exemplar_field("rings", 48, device=ONE_DEVICE).values)
    assert not is_network(exemplar_field("domes", 48, device=ONE_DEVICE).values)


def _congruent_everywhere(src: np.ndarray, out: np.ndarray, vectors: np.ndarray, step: int = 5) -> bool:
    last = np.array(src.shape[1:]) - 1
    return all(any((src[:, oy, ox] == out[:, y, x]).all() for oy, ox in lattice_origins((y, x), vectors, last))
               for y in range(0, out.shape[1], step) for x in range(0, out.shape[2], step))


def test_the_tiled_scan_follows_the_same_lattice_across_its_tiles():
    """2 x 2 tiles on threads: the tiles' and corners' blocks are congruent in the whole
    level's coordinates (a tile's own origin would break the lattice at every tile border)."""
    from geosynth.volume.tiled import synthesize_volume_tiled

    res = synthesize_volume_tiled(_periodic_slab(), (8, 128, 128), (2, 2), levels=2, block=16, seed=3,
                                  device=ONE_DEVICE, band=BAND, method="graphcut", scheduler="threads", workers=1,
                                  progress=False, lattice=True)
    assert res.lattice is not None and res.lattice_text.startswith("lattice")
    assert _congruent_everywhere(res.source, res.quantized, res.lattice.vectors, step=3)


def test_a_lattice_asked_for_where_no_scan_follows_it_is_said_unused():
    vol = synthesize_volume(_periodic_slab(), (8, 64, 64), levels=1, block=16, seed=3, device=ONE_DEVICE,
                            progress=False, band=BAND, method="optimize", lattice=True)
    assert vol.lattice is None and vol.lattice_text.startswith("lattice: not used")
