"""Road-plane construction (paper Section III): SVD fit, availability detection, RANSAC FE."""
