"""What informs the product, beside it: studies, benchmarks and their logs (README.md); never imported by it."""
