"""The HTML report: the chain behind it, its sections and its figures."""
