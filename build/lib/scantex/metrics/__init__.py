"""Measuring what scantex did: geometry kept (it must be exactly), texture against a reference."""
