"""Clustering face features: batched spherical k-means."""
from .spherical_kmeans import KMeansResult, spherical_kmeans

__all__ = ["KMeansResult", "spherical_kmeans"]
