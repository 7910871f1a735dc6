"""Shared pytest configuration: ``--slow`` enables the Monte Carlo tests, ``--campaign`` the
few campaigns that take minutes each (not run by CI; docs/testing.md)."""

import os

import pytest
from hypothesis import settings

# CI runs the property tests with a fixed derandomised seed, so that a CI verdict can be
# reproduced; local runs keep exploring new examples.
settings.register_profile("ci", derandomize=True)
if os.environ.get("CI"):
    settings.load_profile("ci")


def pytest_addoption(parser: pytest.Parser) -> None:
    parser.addoption("--slow", action="store_true", default=False,
                     help="also run tests marked slow (Monte Carlo acceptance runs)")
    parser.addoption("--campaign", action="store_true", default=False,
                     help="also run tests marked campaign (Monte Carlo campaigns of several "
                          "minutes each; implies --slow)")


def pytest_collection_modifyitems(config: pytest.Config, items: list[pytest.Item]) -> None:
    if config.getoption("--campaign"):
        return
    slow = config.getoption("--slow")
    skip_slow = pytest.mark.skip(reason="slow: run with --slow")
    skip_campaign = pytest.mark.skip(reason="campaign of several minutes: run with --campaign")
    for item in items:
        if "campaign" in item.keywords:
            item.add_marker(skip_campaign)
        elif "slow" in item.keywords and not slow:
            item.add_marker(skip_slow)


@pytest.fixture(autouse=True)
def _no_progress_lines(monkeypatch: pytest.MonkeyPatch) -> None:
    """No progress lines on stderr (fdi.progress) in tests that count a command's stderr
    lines: on a loaded machine a command's work can pass the 3 s after which progress is
    shown. tests/fdi/test_progress.py turns it back on where it is under test."""
    monkeypatch.setenv("RIMU_PROGRESS", "0")
