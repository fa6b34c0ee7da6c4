"""Nordland variant study (research/studies/nordland_variants.py): the rows and the top-k query, no dataset needed."""
import numpy as np

from research.studies import nordland_variants as nv
from tests.reference import ReferenceMemory
from vpr import sdr
from vpr.shosm import SequenceMemory


def test_grid_rows_are_unique_and_the_358_subset_adds_the_pure_python_rows():
    full, small = nv.grid_rows("full"), nv.grid_rows("358")
    assert len({r[0] for r in small}) == len(small)
    kinds = {r[1] for r in small} - {r[1] for r in full}
    assert kinds == {"topk", "segments"}


def test_topk_query_with_the_threshold_count_is_the_oracle_query():
    # every query frame is a database place: with k_active = the number of columns a place created,
    # top-k picks exactly the place's minicolumns, so the winners are the oracle's (learning off)
    places = sdr.random_sdrs(12, seed=0)
    kw = dict(p_extra=0.0, k_active=0, seed=1)
    mem, ref = SequenceMemory(**kw), ReferenceMemory(**kw)
    mem.run(places)
    for t in range(12):
        ref.step(places[t].indices)
    ref.reset()
    want = [sorted(ref.step(places[t].indices, learn=False)) for t in range(12)]
    got = nv.binary_topk_query(mem, places, k_active=10)
    assert [got[t].indices.tolist() for t in range(12)] == want
    assert np.diff(got.indptr).min() >= 10


def test_main_names_the_missing_dataset(tmp_path, capsys):
    assert nv.main(["--out", str(tmp_path / "o"), "--data", str(tmp_path / "none"), "--no-progress"]) == 2
    assert str(tmp_path / "none") in capsys.readouterr().err
