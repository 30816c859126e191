//! Named reward presets (docs/science.md#reward-presets): sets of reward
//! parameter values with a recommended w1 grid. `paper` is the paper's reward
//! and the default everywhere.

use serde::Serialize;
use serde_json::{json, Value};

use super::{EnvError, RewardConfig};

/// A named set of reward parameters.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct RewardPreset {
    /// Name used by `reward_preset` and `--preset`.
    pub name: &'static str,
    /// One line on what it is for.
    pub description: &'static str,
    /// `RewardConfig` fields it sets (a JSON object); every other field
    /// keeps the paper's value.
    pub params: Value,
    /// Recommended w1 grid (at least 7 values over at least two decades).
    pub w1_grid: Vec<f64>,
}

/// The name of the default preset.
pub const DEFAULT_PRESET: &str = "paper";

/// Every preset, the default first.
pub fn presets() -> Vec<RewardPreset> {
    vec![RewardPreset {
        name: DEFAULT_PRESET,
        description: "the paper's reward: h_t - w1 ||a|| per step, 1000 - 10 t on success",
        params: json!({}),
        w1_grid: vec![0.1, 0.5, 1.0, 2.0, 4.0, 8.0, 16.0],
    },
    RewardPreset {
        name: "power",
        description: "departs from the paper: w1 prices squared mechanical power, holding still is free, every step before standing costs (docs/science.md#reward-presets)",
        params: json!({
            "effort_term": "power",
            "effort_exponent": 2.0,
            "height_offset": 1.0,
            "tall_reward": 0.0,
            "success_step_cost": 1.0
        }),
        w1_grid: vec![0.01, 0.0215, 0.0464, 0.1, 0.215, 0.464, 1.0],
    }]
}

/// The preset called `name`.
pub fn preset(name: &str) -> Result<RewardPreset, EnvError> {
    let all = presets();
    let names: Vec<&str> = all.iter().map(|p| p.name).collect();
    all.iter().find(|p| p.name == name).cloned().ok_or_else(|| {
        EnvError::InvalidConfig(format!(
            "unknown reward preset {name:?} (known: {})",
            names.join(", ")
        ))
    })
}

impl RewardPreset {
    /// The paper's reward with this preset's values set.
    pub fn reward(&self) -> Result<RewardConfig, EnvError> {
        let mut v = serde_json::to_value(RewardConfig::default())
            .map_err(|e| EnvError::InvalidConfig(e.to_string()))?;
        overlay(&mut v, &self.params);
        let r: RewardConfig = serde_json::from_value(v)
            .map_err(|e| EnvError::InvalidConfig(format!("preset {}: {e}", self.name)))?;
        r.validate()?;
        Ok(r)
    }
}

/// Writes every field of `patch` over `base`, recursing into objects, so that
/// a partial configuration overrides a preset's values one field at a time.
/// Fields `base` lacks are copied too: strict parsing of the result still
/// refuses unknown names.
pub fn overlay(base: &mut Value, patch: &Value) {
    match (base, patch) {
        (Value::Object(b), Value::Object(p)) => {
            for (k, v) in p {
                match b.get_mut(k) {
                    Some(slot) => overlay(slot, v),
                    None => {
                        b.insert(k.clone(), v.clone());
                    }
                }
            }
        }
        (b, p) => *b = p.clone(),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_paper_preset_is_the_default_reward() {
        assert_eq!(
            preset("paper").unwrap().reward().unwrap(),
            RewardConfig::default()
        );
        assert_eq!(presets()[0].name, DEFAULT_PRESET);
    }

    #[test]
    fn every_preset_is_valid_and_spans_two_decades() {
        for p in presets() {
            p.reward().unwrap();
            assert!(p.w1_grid.len() >= 7, "{}", p.name);
            let (lo, hi) = (p.w1_grid[0], *p.w1_grid.last().unwrap());
            assert!(hi / lo >= 100.0 - 1e-9, "{}: {lo}..{hi}", p.name);
            assert!(p.w1_grid.windows(2).all(|w| w[0] < w[1]), "{}", p.name);
            assert!(p.params.get("w1").is_none(), "{}", p.name);
        }
    }

    #[test]
    fn overlay_replaces_only_the_fields_given() {
        let mut base =
            serde_json::json!({"reward": {"w1": 1.0, "height_offset": 1.0}, "max_steps": 60});
        overlay(
            &mut base,
            &serde_json::json!({"reward": {"w1": 3.0, "typo": 1}}),
        );
        assert_eq!(
            base,
            serde_json::json!({"reward": {"w1": 3.0, "height_offset": 1.0, "typo": 1}, "max_steps": 60})
        );
    }

    #[test]
    fn an_unknown_preset_names_the_known_ones() {
        let e = preset("nope").unwrap_err().to_string();
        assert!(e.contains("paper"), "{e}");
    }
}
