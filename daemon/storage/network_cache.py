"""The network facts (time constants, stability limit, deformation per watt) cached in the
data directory, keyed on the network file's content (issue 30): a large network's
eigenvalues are paid once per file, by ``thermocomp model info --data-dir`` and by
``GET /networks``, whichever comes first. The computation stays in the pure core
(daemon/model/network.py ``network_facts``); only the file I/O is here.

An entry is ``<data_dir>/cache/network-facts/<sha256>.json``, the hash over the file's bytes
and :data:`FACTS_VERSION` (raised when the facts' computation changes, so an old entry is
never read). An unreadable entry is recomputed and rewritten; a cache that cannot be written
costs the recomputation next time, never an error.
"""

from __future__ import annotations

import dataclasses
import hashlib
import json
import logging
import os
import tempfile
from pathlib import Path

from daemon.model.network import NetworkFacts, ThermalNetwork, network_facts

logger = logging.getLogger(__name__)

CACHE_FOLDER = Path("cache") / "network-facts"
#: 2: the fastest rate by inertia bisection (daemon/model/spectrum.py)
FACTS_VERSION = 2


def cache_path(network_file: Path, data_dir: Path) -> Path:
    digest = hashlib.sha256(f"network-facts {FACTS_VERSION}\n".encode())
    digest.update(Path(network_file).read_bytes())
    return Path(data_dir) / CACHE_FOLDER / f"{digest.hexdigest()}.json"


def cached_network_facts(
    network_file: Path, network: ThermalNetwork, data_dir: Path | None
) -> NetworkFacts:
    """``network_facts(network)``, read from the cache of ``data_dir`` when the file
    ``network_file`` (the one ``network`` was loaded from) has been seen, else computed and
    stored there; without a data directory, computed."""
    if data_dir is None:
        return network_facts(network)
    try:
        path = cache_path(network_file, data_dir)
    except OSError:
        return network_facts(network)
    try:
        return NetworkFacts(**json.loads(path.read_text(encoding="utf-8")))
    except FileNotFoundError:
        pass
    except (OSError, ValueError, TypeError) as err:
        logger.warning("%s: unreadable cache entry (%s): recomputed", path, err)
    facts = network_facts(network)
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        with tempfile.NamedTemporaryFile(
            "w", encoding="utf-8", dir=path.parent, suffix=".tmp", delete=False
        ) as handle:
            json.dump(dataclasses.asdict(facts), handle)
        os.replace(handle.name, path)  # whole or absent, even if two writers race
    except OSError as err:
        logger.warning("cannot cache the facts of %s in %s: %s", network_file, path.parent, err)
    return facts
