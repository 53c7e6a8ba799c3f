"""The live nodes reading a flight stack's own topics through a topic map (issue #27: live without a relay)."""
