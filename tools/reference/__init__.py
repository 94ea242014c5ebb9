"""Reference implementations run beside vislam for comparison (tools/reference/README in README.md):
vl_reference (the same filter in plain NumPy), compare (both on one log), isam2 (GTSAM's iSAM2)."""
