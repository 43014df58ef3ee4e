"""Classical trackers from the papers, as reference policies and comparison trackers."""
