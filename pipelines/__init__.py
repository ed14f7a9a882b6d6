"""Assembly, training loop and evaluation."""
