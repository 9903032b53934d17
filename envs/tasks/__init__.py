"""The built-in tasks, one file each (their MJCF models are in `assets/`); `envs` registers them.

A task module imports the env API modules (`envs.core`, `envs.mjx_env`, `envs.assets`) and,
where it shares a task's equations, that task's module; never the `envs` package itself."""
