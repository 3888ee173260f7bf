"""Real footage into captures: silhouette extraction and calibrated cameras in and out."""
