"""Design tool: limit estimation and parameter selection (thesis 3.5, 4.1)."""
