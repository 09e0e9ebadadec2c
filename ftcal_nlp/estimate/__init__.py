"""The estimators: hanging (hexapod legs), standing (legged robots), free loads (any orientation), model selection,
the naive baseline, sensor noise and the calibration covariance (docs/architecture.md)."""
