pub mod analysis;
pub mod api;
pub mod env;
pub mod sim;
pub mod ppo;
pub mod sample;
