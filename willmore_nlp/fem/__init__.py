"""Finite elements: symbolic element kernels and numeric assembly."""
