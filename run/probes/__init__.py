"""One-off measurements behind a design choice, each answering one question."""
