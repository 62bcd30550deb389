"""Offline views of recordings (Rerun)."""
