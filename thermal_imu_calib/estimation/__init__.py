"""Estimation: stationary detection, segment statistics, estimators, model selection."""
