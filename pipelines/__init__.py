"""End-to-end runs: paper reproduction, folder/video matching, dataset benchmarks."""
