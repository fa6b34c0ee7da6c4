"""The orderings of the paper's Fig. 3, at the paper's sizes, with fixed seeds."""
import json

import numpy as np

from pipelines import paper_fig3
from pipelines.cli import main as cli_main

SEEDS = (0, 1, 2)


def _mean(method, p, a, n, key):
    return np.mean([paper_fig3.run_curve(method, p, a, n, seed=s)[key] for s in SEEDS])


def test_rshosm_keeps_recall_that_shosm_loses():
    shosm = _mean("rshosm", 0.0, 0, 0.0, "recall_at_100p")
    rshosm = _mean("rshosm", 0.05, 0, 0.0, "recall_at_100p")
    assert rshosm > 0.95
    assert shosm < rshosm - 0.1


def test_aliasing_costs_pairwise_precision_not_rshosm():
    pw = _mean("pairwise", 0.0, 5, 0.0, "auc_pr")
    rs = _mean("rshosm", 0.05, 5, 0.0, "auc_pr")
    assert _mean("pairwise", 0.0, 5, 0.0, "recall_at_100p") == 0.0  # aliased pairs tie with true ones
    assert rs > pw + 0.1


def test_aliasing_and_noise_rshosm_clearly_ahead():
    pw = _mean("pairwise", 0.0, 5, 0.5, "auc_pr")
    rs = _mean("rshosm", 0.05, 5, 0.5, "auc_pr")
    assert rs > pw + 0.15


def test_noise_alone_hurts_neither_much():
    assert _mean("pairwise", 0.0, 0, 0.5, "auc_pr") > 0.9
    assert _mean("rshosm", 0.05, 0, 0.5, "auc_pr") > 0.9


def test_cli_writes_plots_and_metrics(tmp_path, capsys):
    out = tmp_path / "fig3"
    assert cli_main(["paper-fig3", "--out", str(out), "--seeds", "1", "--loops", "4"]) == 0
    for name in ("fig3_left.png", "fig3_right.png", "metrics.json", "report.html"):
        assert (out / name).stat().st_size > 0
    m = json.loads((out / "metrics.json").read_text())
    assert set(m["curves"]) == set(paper_fig3.CURVES_LEFT) | set(paper_fig3.CURVES_RIGHT)
    for c in m["curves"].values():
        assert 0 <= c["auc_pr"] <= 1 and 0 <= c["recall_at_100p"] <= 1
    assert "SHOSM" in capsys.readouterr().out


def test_cli_bad_argument_is_one_line(capsys):
    assert cli_main(["paper-fig3", "--out", "/tmp/x", "--seeds", "0"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "seeds must be >= 1" in err[0]
