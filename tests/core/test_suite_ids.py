"""The suite can be split over processes (scripts/test.sh, pytest-xdist): every test has a node id
of its own, or xdist's scheduler, which keys tests by node id, runs one test per shared id.

Checked on the run's own collection (`session.items`, what every xdist worker collects and the
scheduler hands out by id), after `tests/conftest.py` gave shared ids their own. Until 2026-12-03
this collected the whole suite again in a child pytest, 20 s of a CI worker for the same list."""

from __future__ import annotations

from collections import Counter

import pytest


def test_every_node_id_is_unique(request: pytest.FixtureRequest) -> None:
    ids = [item.nodeid for item in request.session.items]
    if any(i.startswith("tests/api/test_api_schema.py::") for i in ids):
        # schemathesis' generated tests, one per API operation, all named after one function
        assert any("test_openapi_conformance[" in i for i in ids)
    shared = [i for i, n in Counter(ids).items() if n > 1]
    assert not shared, shared
