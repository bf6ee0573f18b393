"""Curation: track quality, behaviour labels and ego choice, from a scenario and its map."""
