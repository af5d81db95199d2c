"""Evaluation metrics: geometry (Chamfer-L1, F1, alignment) and images (PSNR, SSIM, albedo RMSE)."""

from .geometry import (DEFAULT_SAMPLES, DEFAULT_TAUS, SurfaceSamples, align_by_icp, align_similarity,
                       corresponding_albedo, geometry_metrics, sample_surface)
from .image import albedo_rmse, image_metrics, psnr, rmse, ssim

__all__ = ["DEFAULT_SAMPLES", "DEFAULT_TAUS", "SurfaceSamples", "align_by_icp", "align_similarity",
           "albedo_rmse", "corresponding_albedo", "geometry_metrics", "image_metrics", "psnr", "rmse",
           "sample_surface", "ssim"]
