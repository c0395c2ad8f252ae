"""The sparse decay rates of a thermal network (daemon/model/spectrum.py) against the dense
eigen-solver (the oracle) on networks small enough for both, and the network facts' cache
keyed on the network file (daemon/storage/network_cache.py)."""

from __future__ import annotations

import json
import time
from pathlib import Path

import numpy as np
import pytest
import scipy.sparse as sp

from daemon.model.network import MAX_NETWORK_NODES, decay_rates_per_s, network_facts
from daemon.model.presets import load_network
from daemon.model.spectrum import count_below, largest_eigenvalue, smallest_eigenvalue
from daemon.storage.network_cache import cached_network_facts

BAR = """name = "bar"
[[segments]]
length_mm = 635.0
width_mm = 25.4
thickness_mm = 6.35
node_spacing_mm = {spacing}
h_w_per_m2k = 2.5
material = "6061-T6"
[[holes]]
name = "shaft"
position_mm = 100.0
"""


def _bar(tmp_path: Path, spacing_mm: float) -> Path:
    path = tmp_path / f"bar-{spacing_mm:g}.toml"
    path.write_text(BAR.format(spacing=spacing_mm))
    return path


@pytest.mark.parametrize("spacing_mm", [10.0, 2.0, 0.8])
def test_sparse_rates_equal_the_dense_ones(tmp_path: Path, spacing_mm: float) -> None:
    network = load_network(_bar(tmp_path, spacing_mm))
    dense = decay_rates_per_s(network)  # well under DENSE_LIMIT: the dense solver
    sparse = decay_rates_per_s(network, dense_limit=0)
    assert sparse[0] == pytest.approx(dense[0], rel=1e-9)
    assert sparse[1] == pytest.approx(dense[1], rel=1e-11)
    assert sparse[1] >= dense[1] * (1 - 1e-14)  # the fastest rate is bracketed from above


def test_inertia_and_the_largest_eigenvalue_of_a_random_sparse_matrix() -> None:
    """Not a chain: a random sparse symmetric positive definite matrix (a mesh-like
    pattern), so the factorisation has fill-in and a non-trivial ordering."""
    rng = np.random.default_rng(3)
    size = 300
    links = sp.random(size, size, density=0.02, random_state=rng, format="csr")
    links = links + links.T
    laplacian = sp.diags(np.asarray(links.sum(axis=1)).ravel()) - links
    matrix = sp.csc_matrix(laplacian + sp.diags(rng.uniform(0.01, 1.0, size)))
    eigenvalues = np.linalg.eigvalsh(matrix.toarray())
    for shift in (eigenvalues[0] * 0.5, float(np.median(eigenvalues)) + 1e-7, 1e9):
        assert count_below(matrix, shift) == int(np.count_nonzero(eigenvalues < shift))
    assert largest_eigenvalue(matrix) == pytest.approx(eigenvalues[-1], rel=1e-11)
    assert smallest_eigenvalue(matrix) == pytest.approx(eigenvalues[0], rel=1e-9)


@pytest.mark.slow
def test_a_10000_node_network_in_seconds(tmp_path: Path) -> None:
    """13 min 14 s before (plain Lanczos for the fastest rate). The slowest rate of a
    uniform bar is known in closed form to the discretisation's accuracy; here it is checked
    against the 1,000-node bar's, whose dense solution the test above pins."""
    # as fine as a network may be (MAX_NETWORK_NODES, counted before building)
    network = load_network(_bar(tmp_path, 0.0636))
    assert 0.99 * MAX_NETWORK_NODES <= network.node_count <= MAX_NETWORK_NODES
    started = time.process_time()
    slow, fast = decay_rates_per_s(network)
    assert time.process_time() - started < 20.0
    coarse = decay_rates_per_s(load_network(_bar(tmp_path, 0.635)))
    assert slow == pytest.approx(coarse[0], rel=1e-3)
    # the fastest: above the Rayleigh quotient of the bar's zig-zag mode (a lower bound; the
    # shaft's node has a faster local mode), under Gershgorin's bound, and just one
    # eigenvalue above it (the inertia count, checked against the dense oracle above)
    scale = 1.0 / np.sqrt(network.capacitance_j_per_c)
    symmetric = sp.diags(scale) @ network.conductance_matrix @ sp.diags(scale)
    zigzag = (-1.0) ** np.arange(network.node_count)
    rayleigh = float(zigzag @ (symmetric @ zigzag)) / float(zigzag @ zigzag)
    assert rayleigh <= fast <= float(abs(symmetric).sum(axis=1).max())
    below = count_below(sp.csc_matrix(symmetric), fast * (1 - 1e-9))
    assert below == network.node_count - 1


def test_facts_are_cached_by_the_files_content(tmp_path: Path) -> None:
    path = _bar(tmp_path, 10.0)
    data_dir = tmp_path / "data"
    network = load_network(path)
    first = cached_network_facts(path, network, data_dir)
    cached = list((data_dir / "cache" / "network-facts").glob("*.json"))
    assert len(cached) == 1 and first == network_facts(network)
    # the cache is what is read back: a doctored entry shows through
    entry = json.loads(cached[0].read_text())
    entry["slowest_time_constant_s"] = 123.0
    cached[0].write_text(json.dumps(entry))
    assert cached_network_facts(path, network, data_dir).slowest_time_constant_s == 123.0
    # another content is another entry
    path.write_text(BAR.format(spacing=5.0))
    changed = load_network(path)
    assert cached_network_facts(path, changed, data_dir).node_count == changed.node_count
    assert len(list((data_dir / "cache" / "network-facts").glob("*.json"))) == 2
    # a damaged entry is recomputed, never an error; no data directory: no cache
    cached[0].write_text("not json")
    path.write_text(BAR.format(spacing=10.0))
    assert cached_network_facts(path, network, data_dir) == network_facts(network)
    assert cached_network_facts(path, network, None) == network_facts(network)
