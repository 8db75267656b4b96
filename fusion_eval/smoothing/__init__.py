"""Offline smoothing beside the filter (``smoother.method``).

``rts``: the Rauch-Tung-Striebel backward pass over the filter's own models (:mod:`.rts`), fed by a compact
record of the forward pass (:mod:`.record`). The smoothed estimate is evaluated and reported like the fused one,
under the name ``smoothed``.
"""
