pub mod analysis;
pub mod api;
pub mod env;
pub mod optimize;
pub mod ppo;
pub mod sample;
pub mod sim;
#[cfg(any(test, feature = "test-support"))]
pub mod test_support;
