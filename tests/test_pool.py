"""The worker pool: objects shared with forked workers without pickles (Pool.share)."""

from __future__ import annotations

import numpy as np
import pytest


class _NoPickle:
    """An object a job can only get by inheritance: pickling it fails."""

    def __init__(self, value):
        self.value = value

    def __reduce__(self):
        raise TypeError("pickled")


def _value_of(obj):
    return obj.value


def test_a_shared_object_reaches_forked_workers_without_a_pickle():
    """Pool.share: objects registered before the pool's first job (which forks the workers) are named by token;
    one registered later is pickled as usual; the registry forgets them when the pool ends."""
    from fusion_eval import pool

    with pool.executor(2) as ex:
        early = ex.share(_NoPickle(41))
        big = ex.share(np.arange(10))
        assert ex.submit(_value_of, early).result() == 41
        assert ex.submit(np.sum, big).result() == 45
        late = ex.share(_NoPickle(7))                    # the workers exist: it must travel as a pickle
        with pytest.raises(TypeError, match="pickled"):
            ex.submit(_value_of, late).result()
        assert ex.submit(np.sum, ex.share(np.arange(4))).result() == 6
    assert not pool._SHARED
    assert pool.Inline().share(early.obj) is early.obj
