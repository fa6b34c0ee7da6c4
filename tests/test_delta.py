"""Delta Descriptors, the field's simplest training-free sequence method, as a method beside rSHOSM-seq."""
import numpy as np
import pytest

from tests.reference import delta_descriptors_by_convolution
from vpr import methods
from vpr.delta import delta_descriptors
from vpr.similarity import cosine
from vpr.types import EncodedTraverse


@pytest.mark.parametrize("L", [2, 8, 16])
def test_delta_descriptors_are_the_papers_convolution(L):
    x = np.random.default_rng(L).random((50, 7))
    x[20:30] = 0.5  # a stretch standing still: deltas of zero sum keep the raw descriptor
    np.testing.assert_allclose(delta_descriptors(x, L), delta_descriptors_by_convolution(x, L), atol=1e-6)
    for bad in (3, 0):
        with pytest.raises(ValueError, match="L"):
            delta_descriptors(x, bad)


def test_the_delta_method_compares_delta_descriptors_by_cosine():
    rng = np.random.default_rng(0)
    db, q = rng.random((30, 6)).astype(np.float32), rng.random((25, 6)).astype(np.float32)
    res = methods.get("delta", L=8).match(EncodedTraverse([str(i) for i in range(30)], desc=db),
                                          EncodedTraverse([str(i) for i in range(25)], desc=q))
    np.testing.assert_allclose(res.similarity, cosine(delta_descriptors(db, 8), delta_descriptors(q, 8)), atol=1e-6)
    assert res.accepted.all() and "desc" in methods.get_class("delta").required_inputs
