"""``fusion-eval simulate``: synthetic KITTI-style datasets with known truth."""
