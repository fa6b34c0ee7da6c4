"""A loop rule is one class and one registry line: it decides in batch, online, saved and resumed, and by name."""
import numpy as np
import pytest
import scipy.sparse as sp

from vpr import methods, sdr
from vpr.shosm import LOOP_RULES, LoopDetector, LoopRule, loop_evidence
from vpr.types import Column, Decider, Decision, EncodedTraverse


class EveryFifth(LoopRule):
    """A toy rule: the best earlier frame is accepted on every fifth frame."""

    def _decide(self, column: Column) -> Decision:
        b, z = column.best()
        return Decision(b, z, b >= 0 and column.frame % 5 == 0, 0.0, column.frame, column)

    def new_session(self) -> None:
        pass

    def state(self):
        return {"frames": self.frames}, {}

    def load_state(self, header, arrays):
        self.frames = int(header["frames"])
        return self


@pytest.fixture
def toy(monkeypatch):
    monkeypatch.setitem(LOOP_RULES, "every5", EveryFifth)  # the one registry line


def _stream():
    lap = sdr.random_sdrs(40, 256, 12, seed=3)
    return sp.vstack([lap, lap, lap]).tocsr()  # three laps of one loop


def test_a_registered_rule_decides_in_batch_online_and_after_a_restart(toy, tmp_path):
    x = _stream()
    # the rule's own decisions, unconfirmed by the frames after them and none accepted back (each final at once)
    batch = loop_evidence(x, exclude=10, n_inputs=256, loop_rule="every5", confirm_frames=0,
                          backfill_frames=0).decision
    has = batch.best >= 0
    assert has.sum() > 60 and (batch.accepted == (has & (np.arange(x.shape[0]) % 5 == 0))).all()
    det = LoopDetector(exclude=10, n_inputs=256, loop_rule="every5", confirm_frames=0, backfill_frames=0)
    online = [det.update(x[j]) for j in range(70)]
    det.save(tmp_path / "det.npz")
    det = LoopDetector.load(tmp_path / "det.npz")  # the rule comes back by its name in the saved conf
    online += [det.update(x[j]) for j in range(70, x.shape[0])]
    assert isinstance(det.stream.decider, EveryFifth)
    np.testing.assert_array_equal(Decision.stack(online).accepted, batch.accepted)
    np.testing.assert_array_equal(Decision.stack(online).best, batch.best)


def test_the_method_takes_a_rule_by_name_and_refuses_an_unknown_one(toy):
    x = _stream()
    m = methods.get("rshosm-seq", loop_rule="every5", n_inputs=256, backfill_frames=0)
    res = m.loops(EncodedTraverse([f"f{k}" for k in range(x.shape[0])], sdr=x), exclude=10)
    assert res.accepted.any() and not res.accepted[np.arange(x.shape[0]) % 5 != 0].any()
    with pytest.raises(ValueError, match=r"rshosm-seq: loop_rule 'nope' is not a loop rule \(known: every5, path\)"):
        methods.get("rshosm-seq", loop_rule="nope")


def test_every_decider_keeps_the_one_contract():
    from vpr.shosm import LoopDecider, PathDecider
    from vpr.verify import GeometricOpinion

    for cls in (LoopDecider, PathDecider, GeometricOpinion, EveryFifth):
        assert issubclass(cls, Decider)
        assert not getattr(cls, "__abstractmethods__", None), cls  # every hook implemented
    with pytest.raises(TypeError, match="takes a Column"):
        PathDecider().decide(np.zeros(3))
    from pipelines.stream import StreamEncoder
    from vpr.types import FrameEncoder

    assert issubclass(StreamEncoder, FrameEncoder) and not StreamEncoder.__abstractmethods__
