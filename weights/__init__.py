"""The shipped VCR-Net weights, installed as package data (``vcr_odom.weights``); see MODEL_CARD.md."""
