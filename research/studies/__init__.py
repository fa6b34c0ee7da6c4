"""Research studies: not installed, not part of the product. Run as ``python -m studies.<name>``; see README.md."""
