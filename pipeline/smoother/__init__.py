"""The batch smoother (observer name ``batch``): keyframe poses, landmarks and biases by nonlinear least
squares, seeded by an observer. Modules: ``settings`` (the ``batch`` config section), ``preintegration``
(compiled odometry preintegration, residuals and trajectories), ``seed`` (initial guesses), ``graph`` (the factor
graph and its Levenberg-Marquardt loop), ``solver`` (its compiled normal equations, the chain-plus-border solve and
the covariances; GTSAM solves the same graph only in ``benchmarks/batch_gtsam.py``), ``candidates`` (other starts
when the first solution is doubtful), ``estimator`` (the registry entry)."""
