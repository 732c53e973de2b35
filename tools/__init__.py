"""Command-line tools: certificates and Zenoh security configs (gen_certs), the soak run (soak)."""
