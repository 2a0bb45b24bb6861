"""FFT water surface simulation on NVIDIA Warp (knows nothing of rendering)."""
