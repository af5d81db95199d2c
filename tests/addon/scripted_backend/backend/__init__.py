"""A scripted stand-in for the backend, used only to test the add-on's process handling."""
