"""Code every zensim service shares: settings, Zenoh sessions, logging, shutdown, pacing."""
