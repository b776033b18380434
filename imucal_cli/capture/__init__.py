"""Capture and import: serial streams, protocols, guided plans, file importers."""
