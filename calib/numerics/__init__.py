"""Rotation numerics shared by the estimators: quaternion products and attitude from rates."""
