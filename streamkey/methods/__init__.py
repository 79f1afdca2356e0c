"""Keyframe extraction methods: one module per method, offline `extract` + online `Online`."""
