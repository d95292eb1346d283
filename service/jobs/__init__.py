"""Job model, queue (Huey on SQLite or Redis), runner, heartbeat and reaper."""
