"""Gain tuning (``slamobs tune``): an observer's gains searched on logs with ground truth.

``space`` maps each observer's :class:`GainSpec` search ranges and stability limits to Optuna parameters,
``worker`` scores one (gains, log) pair in a batch worker process (the log read and aligned once per process),
``study`` drives Optuna's TPE sampler over the batch executor's pools (local processes or Dask) with its
state in ``OUT`` (resumable), ``results`` writes the trials table, ``gains.yaml``, the plot and the
leave-one-log-out validation.
"""
