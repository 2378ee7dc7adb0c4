"""The estimation engine: the filter, its compiled release and its state layout."""
