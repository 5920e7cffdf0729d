"""Device drivers: the lowest layer. Never imports the controller or the tasks."""
