"""pkmcal."""
