"""Estimation: six-state process models (RK4 with exact Jacobians), the filterpy EKF and the
gtsam factor graph (batch smoothing and fixed-lag iSAM2)."""
