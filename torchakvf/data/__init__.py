"""Datasets over files written by ``torchakvf features``."""
from .dataset import FeatureDataset, collate_packed, load_feature_file

__all__ = ["FeatureDataset", "collate_packed", "load_feature_file"]
