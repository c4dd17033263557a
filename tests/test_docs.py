"""The README's key reference is the schema's: regenerate it with `python -m app.config.docs`."""
import pathlib

from app.config.docs import reference
import pytest

pytestmark = pytest.mark.unit


def test_readme_reference_matches_schema():
    readme = (pathlib.Path(__file__).resolve().parents[1] / "README.md").read_text()
    assert reference() in readme
