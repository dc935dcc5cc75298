"""Fixtures made by tests/pytest.rs (run through `cargo test`): DENSETACT_TEST_DIR holds a bundle,
a simulated capture session, a dataset and `infer predict`'s answers for some frames."""

import csv
import json
import os
from pathlib import Path

import importlib

import pytest


def peer(module: str):
    """A peer library a test compares with or runs under (torch, onnxruntime): skipped where it is
    not installed, unless DENSETACT_REQUIRE names it (CI installs them and names them, so that a
    missing one fails there instead of passing as a skip)."""
    required = {m.strip() for m in os.environ.get("DENSETACT_REQUIRE", "").split(",") if m.strip()}
    if module in required:
        return importlib.import_module(module)
    return pytest.importorskip(module)


@pytest.fixture(scope="session")
def root() -> Path:
    path = os.environ.get("DENSETACT_TEST_DIR")
    if not path:
        pytest.fail("run these through `cargo test -p densetact-python -- --include-ignored`, which makes the fixtures")
    return Path(path)


@pytest.fixture(scope="session")
def bundle(root):
    return root / "bundle"


@pytest.fixture(scope="session")
def session(root):
    return root / "session"


@pytest.fixture(scope="session")
def cases(root):
    return json.loads((root / "cases.json").read_text())


@pytest.fixture(scope="session")
def rows(session):
    with open(session / "captures.csv", newline="") as f:
        return list(csv.DictReader(f))
