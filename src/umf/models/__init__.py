"""Neural networks of UMF: the motion VAE, the flow denoisers and their adapters."""
