"""Realism study (research/studies/realism.py) on a tiny render."""
import pytest

from research.studies import realism


def test_realism_table_rows_and_cli(tmp_path, capsys):
    rows = realism.realism_table("two_seasons", size=(48, 32), n_frames=20, progress=False)
    kinds = {r["kind"] for r in rows}
    assert kinds == {"same condition", "cross condition"}
    for r in rows:
        assert 0.0 <= r["recall@1"] <= r["recall@5"] <= 1.0 and 0.0 <= r["chance@1"] <= 1.0
    same = [r["recall@1"] for r in rows if r["kind"] == "same condition"]
    chance = [r["chance@1"] for r in rows if r["kind"] == "same condition"]
    assert min(same) > max(chance)  # a re-render of the same conditions is found far above chance
    table = realism.format_table(rows)
    assert all(r["db"] in table and r["query"] in table for r in rows)
    with pytest.raises(ValueError, match="radius"):
        realism.realism_table("two_seasons", radius=0)
