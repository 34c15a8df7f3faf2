"""What every service shares: Zenoh settings, logging over Zenoh, the RPC server, the skeleton."""
