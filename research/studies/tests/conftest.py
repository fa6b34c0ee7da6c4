"""The research's tests run in the whole suite (CI), not in the product's fast subset: each is marked ``slow``."""
import pytest


def pytest_collection_modifyitems(config, items):
    here = str(config.rootpath / "research")
    for item in items:
        if str(item.path).startswith(here):
            item.add_marker(pytest.mark.slow)
