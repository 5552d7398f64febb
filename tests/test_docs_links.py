"""docs/conf.py links TorchRL's, TensorDict's and PyTorch's classes to their
docs (intersphinx) where those sites are reachable, and only there."""

from __future__ import annotations

import runpy
import socket
from pathlib import Path

CONF = Path(__file__).resolve().parents[1] / "docs" / "conf.py"


def test_intersphinx_maps_the_stack_and_leaves_out_what_it_cannot_reach(
    monkeypatch,
):
    monkeypatch.setenv("DOCS_OFFLINE", "1")
    conf = runpy.run_path(str(CONF))
    assert "sphinx.ext.intersphinx" in conf["extensions"]
    assert {"torch", "torchrl", "tensordict"} <= set(conf["INVENTORIES"])
    # offline: no inventory to fetch, so no warning for make docs' -W to fail on
    assert conf["intersphinx_mapping"] == {}
    monkeypatch.delenv("DOCS_OFFLINE")
    reachable = conf["_reachable"]
    with socket.create_server(("127.0.0.1", 0)) as server:
        port = server.getsockname()[1]
        assert reachable(f"http://127.0.0.1:{port}/rl/stable/")
    assert not reachable(f"http://127.0.0.1:{port}/rl/stable/", timeout=1.0)
