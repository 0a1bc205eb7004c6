"""Drop-in integrations with the mapping frameworks users already run.

Rule: an integration uses the engine and the public API of the plugin packages (never a
private module), exactly as a user's own code would.
"""
