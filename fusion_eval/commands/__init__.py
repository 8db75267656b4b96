"""One module per command, side by side: each holds its command's logic; none imports another command.

What two commands share lives in its own module: the run engine (:mod:`fusion_eval.pipeline`), the
configuration session (:mod:`fusion_eval.session`), variant lookup (:mod:`fusion_eval.variants`), the
worker pool (:mod:`fusion_eval.pool`), metric names (:mod:`fusion_eval.evaluation.keys`) and tables
(:mod:`fusion_eval.tables`). ``cli.py`` only parses arguments, calls these and prints.
"""
