//! Capped exponential backoff with jitter for the worker's retries of
//! transient coordinator failures (the calls themselves are the typed
//! client's, `irlgrid_client`).

use std::time::Duration;

use rand::Rng;

/// Capped exponential backoff with jitter: the n-th delay is drawn
/// uniformly from [d/2, d] with d = min(base * 2^n, max).
#[derive(Debug, Clone)]
pub struct Backoff {
    base: Duration,
    max: Duration,
    n: u32,
}

impl Backoff {
    /// A fresh backoff.
    pub fn new(base: Duration, max: Duration) -> Self {
        Self { base, max, n: 0 }
    }

    /// The next delay.
    pub fn next_delay(&mut self) -> Duration {
        let d = self
            .base
            .saturating_mul(1u32 << self.n.min(20))
            .min(self.max);
        self.n = self.n.saturating_add(1);
        let lo = d / 2;
        lo + (d - lo).mul_f64(rand::thread_rng().gen::<f64>())
    }

    /// Back to the first delay after a success.
    pub fn reset(&mut self) {
        self.n = 0;
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn backoff_grows_to_its_cap_with_jitter_and_resets() {
        let mut b = Backoff::new(Duration::from_millis(100), Duration::from_secs(1));
        let d: Vec<_> = (0..8).map(|_| b.next_delay()).collect();
        assert!(d[0] >= Duration::from_millis(50) && d[0] <= Duration::from_millis(100));
        assert!(d[2] >= Duration::from_millis(200) && d[2] <= Duration::from_millis(400));
        for x in &d[4..] {
            assert!(*x >= Duration::from_millis(500) && *x <= Duration::from_secs(1));
        }
        b.reset();
        assert!(b.next_delay() <= Duration::from_millis(100));
    }
}
