"""Adapters to other libraries' env APIs: Brax (`envs.to_brax`) and Gymnasium (`envs.to_gymnasium`).

They import the env API modules (`envs.core`, `envs.registry`, `envs.wrappers`), never the `envs`
package itself. `gymnasium` is optional: `envs.interop.gymnasium` is imported only on first use."""
