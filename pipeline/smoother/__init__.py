"""The batch smoother (observer name ``batch``): keyframe poses, landmarks and biases by nonlinear least
squares with GTSAM, seeded by an observer. Modules: ``settings`` (the ``batch`` config section),
``preintegration`` (compiled odometry preintegration, residuals and trajectories), ``seed`` (initial guesses),
``graph`` (the GTSAM factor graph and its solve), ``estimator`` (the registry entry)."""
