"""Research studies: not installed, not part of the product. Run as ``python -m research.studies.<name>``
(research/README.md)."""
