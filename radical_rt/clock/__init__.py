"""The SIRU clock reconstruction (time line from counters and bus tags)."""
