"""``fusion-eval tune``: noise tuning with Optuna (:mod:`.space` what is tuned, :mod:`.objectives` what is
minimised, :mod:`.worker` how one trial is scored on its drives, :mod:`.study` the study loop, :mod:`.report` the
outputs)."""
