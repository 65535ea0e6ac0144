"""splat_cpu: a small differentiable 3D Gaussian rasteriser that is fast on a CPU."""
