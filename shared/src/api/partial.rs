//! [`Partial`]: some fields of a science configuration, as a request sends
//! them, and their resolution over a base into the full configuration.
//!
//! Why not a struct of `Option`s per configuration: the configurations nest
//! (`env.reward.w1`, `env.sim.*`), some fields are themselves optional
//! (`training.target_kl: null` switches early stopping off, which an
//! absent field must not), and a hand-kept mirror of every field would
//! drift from the science types it mirrors. A `Partial<T>` is typed by the
//! configuration it patches, reads only a JSON object, and resolves by the
//! one rule the API documents: the given fields, at any depth, over the
//! base (`T::default()` or a preset), parsed strictly as `T` (unknown or
//! ill-typed fields are errors naming their path).

use std::fmt;
use std::marker::PhantomData;

use serde::de::{DeserializeOwned, MapAccess, Visitor};
use serde::{Deserialize, Deserializer, Serialize, Serializer};
use serde_json::{Map, Value};

/// Some fields of a configuration `T` (`ppo::PpoConfig`,
/// `sample::SamplingConfig`, `env::EnvConfig`, `optimize::OptimizeConfig`),
/// at any depth: `{"reward": {"w1": 2.0}}` is a partial `EnvConfig`. On the
/// wire it is exactly that JSON object; anything but an object is refused
/// when the request is read.
pub struct Partial<T> {
    fields: Map<String, Value>,
    of: PhantomData<fn() -> T>,
}

/// Why a [`Partial`] does not resolve: the path of the offending field
/// inside the configuration (`"."` for the whole object, `reward.w1` for a
/// nested one) and serde's message (`unknown field ...`, `invalid type ...`).
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct PartialError {
    /// Path of the field inside the configuration, `.` for the whole.
    pub path: String,
    /// What is wrong with it.
    pub message: String,
}

impl PartialError {
    /// The message under the request field `field`: `training.bogus:
    /// unknown field ...`, or `training: ...` for the whole object.
    pub fn under(&self, field: &str) -> String {
        if self.path == "." {
            format!("{field}: {}", self.message)
        } else {
            format!("{field}.{}: {}", self.path, self.message)
        }
    }
}

impl<T> Partial<T> {
    /// No field: resolves to the base itself.
    pub fn empty() -> Self {
        Self::from_fields(Map::new())
    }

    fn from_fields(fields: Map<String, Value>) -> Self {
        Self {
            fields,
            of: PhantomData,
        }
    }

    /// The given fields of a JSON object, checked only for being an object
    /// (its fields are checked against `T` when it is resolved).
    pub fn from_value(v: Value) -> Result<Self, String> {
        match v {
            Value::Object(fields) => Ok(Self::from_fields(fields)),
            other => Err(format!("expected a JSON object, got {other}")),
        }
    }

    /// Sets one field (a top-level field of `T`) to `value`'s JSON form.
    pub fn with(mut self, field: &str, value: impl Serialize) -> Self {
        let v = serde_json::to_value(value).unwrap_or(Value::Null);
        self.fields.insert(field.to_string(), v);
        self
    }

    /// Whether no field is given.
    pub fn is_empty(&self) -> bool {
        self.fields.is_empty()
    }

    /// The given fields as JSON.
    pub fn fields(&self) -> &Map<String, Value> {
        &self.fields
    }
}

impl<T: Serialize + DeserializeOwned> Partial<T> {
    /// The full configuration: `patches` in order, each over the result of
    /// the one before, over `base`; parsed strictly as `T`.
    pub fn resolve_all<'a>(
        base: &T,
        patches: impl IntoIterator<Item = &'a Partial<T>>,
    ) -> Result<T, PartialError>
    where
        T: 'a,
    {
        let mut merged = serde_json::to_value(base).map_err(|e| PartialError {
            path: ".".into(),
            message: e.to_string(),
        })?;
        for p in patches {
            overlay_map(&mut merged, &p.fields);
        }
        serde_path_to_error::deserialize(merged).map_err(|e| PartialError {
            path: e.path().to_string(),
            message: e.inner().to_string(),
        })
    }

    /// The given fields over `base`, parsed strictly as `T`.
    pub fn resolve_over(&self, base: &T) -> Result<T, PartialError> {
        Self::resolve_all(base, [self])
    }
}

/// Writes every field of `patch` into `base`: objects merge field by field
/// at any depth, anything else replaces what was there.
fn overlay_map(base: &mut Value, patch: &Map<String, Value>) {
    let Value::Object(b) = base else {
        *base = Value::Object(patch.clone());
        return;
    };
    for (k, v) in patch {
        match (b.get_mut(k), v) {
            (Some(slot), Value::Object(p)) => overlay_map(slot, p),
            (Some(slot), _) => *slot = v.clone(),
            (None, _) => {
                b.insert(k.clone(), v.clone());
            }
        }
    }
}

impl<T> Default for Partial<T> {
    fn default() -> Self {
        Self::empty()
    }
}

impl<T> Clone for Partial<T> {
    fn clone(&self) -> Self {
        Self::from_fields(self.fields.clone())
    }
}

impl<T> PartialEq for Partial<T> {
    fn eq(&self, other: &Self) -> bool {
        self.fields == other.fields
    }
}

impl<T> fmt::Debug for Partial<T> {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.debug_tuple("Partial").field(&self.fields).finish()
    }
}

impl<T> Serialize for Partial<T> {
    fn serialize<S: Serializer>(&self, s: S) -> Result<S::Ok, S::Error> {
        self.fields.serialize(s)
    }
}

impl<'de, T> Deserialize<'de> for Partial<T> {
    fn deserialize<D: Deserializer<'de>>(d: D) -> Result<Self, D::Error> {
        struct ObjectOnly;
        impl<'de> Visitor<'de> for ObjectOnly {
            type Value = Map<String, Value>;
            fn expecting(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
                f.write_str("a JSON object of configuration fields")
            }
            fn visit_map<A: MapAccess<'de>>(self, map: A) -> Result<Self::Value, A::Error> {
                Map::deserialize(serde::de::value::MapAccessDeserializer::new(map))
            }
        }
        d.deserialize_map(ObjectOnly).map(Self::from_fields)
    }
}

/// The JSON Schema of a partial `T` (with the `openapi` feature): `T`'s
/// own, inlined, with no field required and no default at any depth (the
/// base supplies both); unknown fields stay refused where `T` refuses them.
#[cfg(feature = "openapi")]
impl<T: schemars::JsonSchema> schemars::JsonSchema for Partial<T> {
    fn schema_name() -> std::borrow::Cow<'static, str> {
        format!("Partial{}", T::schema_name()).into()
    }

    fn schema_id() -> std::borrow::Cow<'static, str> {
        format!("shared::api::Partial<{}>", T::schema_id()).into()
    }

    fn json_schema(generator: &mut schemars::SchemaGenerator) -> schemars::Schema {
        let mut inline = generator
            .settings()
            .clone()
            .with(|s| s.inline_subschemas = true)
            .into_generator();
        let mut schema = T::json_schema(&mut inline);
        if let Some(object) = schema.as_object_mut() {
            relax(object);
            let of = object
                .get("description")
                .and_then(Value::as_str)
                .unwrap_or_default()
                .to_string();
            object.insert(
                "description".into(),
                Value::String(format!(
                    "Some fields of `{}`, at any depth: the given fields over the base \
                     (the defaults or a preset), parsed strictly as the whole. {of}",
                    T::schema_name()
                )),
            );
        }
        schema
    }
}

/// Drops `required` and `default` from a schema and every schema inside it.
#[cfg(feature = "openapi")]
fn relax(schema: &mut Map<String, Value>) {
    schema.remove("required");
    schema.remove("default");
    let each = |v: &mut Value| {
        if let Value::Object(m) = v {
            relax(m);
        }
    };
    for key in ["additionalProperties", "items", "not", "if", "then", "else"] {
        schema.get_mut(key).map(each);
    }
    for key in ["properties", "patternProperties", "$defs"] {
        if let Some(Value::Object(m)) = schema.get_mut(key) {
            m.values_mut().for_each(each);
        }
    }
    for key in ["anyOf", "oneOf", "allOf", "prefixItems"] {
        if let Some(Value::Array(a)) = schema.get_mut(key) {
            a.iter_mut().for_each(each);
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::env::EnvConfig;
    use crate::ppo::PpoConfig;

    #[test]
    fn given_fields_override_the_base_at_any_depth() {
        let p: Partial<EnvConfig> =
            serde_json::from_str(r#"{"reward": {"w1": 2.5}, "max_steps": 40}"#).unwrap();
        let base = EnvConfig::with_w1(9.0);
        let env = p.resolve_over(&base).unwrap();
        assert_eq!(env.reward.w1, 2.5);
        assert_eq!(env.max_steps, 40);
        // Untouched fields keep the base's values, nested ones included.
        assert_eq!(env.reward.success_bonus, base.reward.success_bonus);
        assert_eq!(env.init_noise, base.init_noise);
    }

    #[test]
    fn null_sets_an_optional_field_to_none_and_later_patches_win() {
        let base = PpoConfig {
            target_kl: Some(0.02),
            ..PpoConfig::default()
        };
        let off = Partial::<PpoConfig>::empty().with("target_kl", Option::<f64>::None);
        assert_eq!(off.resolve_over(&base).unwrap().target_kl, None);
        let a = Partial::<PpoConfig>::empty().with("env_steps", 1000u64);
        let b = Partial::<PpoConfig>::empty().with("env_steps", 2000u64);
        let t = Partial::resolve_all(&PpoConfig::default(), [&a, &b]).unwrap();
        assert_eq!(t.env_steps, 2000);
    }

    #[test]
    fn unknown_and_ill_typed_fields_name_their_path() {
        let p: Partial<EnvConfig> = serde_json::from_str(r#"{"reward": {"w1": "x"}}"#).unwrap();
        let e = p.resolve_over(&EnvConfig::default()).unwrap_err();
        assert_eq!(e.path, "reward.w1");
        assert!(
            e.under("env").starts_with("env.reward.w1: invalid type"),
            "{e:?}"
        );
        let p: Partial<PpoConfig> = serde_json::from_str(r#"{"bogus": 1}"#).unwrap();
        let e = p.resolve_over(&PpoConfig::default()).unwrap_err();
        assert!(e.message.contains("unknown field `bogus`"), "{e:?}");
    }

    #[test]
    fn only_an_object_is_read_and_it_writes_back_unchanged() {
        assert!(serde_json::from_str::<Partial<PpoConfig>>("5").is_err());
        assert!(serde_json::from_str::<Partial<PpoConfig>>("[1]").is_err());
        let text = r#"{"env_steps":1000,"hidden":[8,8]}"#;
        let p: Partial<PpoConfig> = serde_json::from_str(text).unwrap();
        assert_eq!(serde_json::to_string(&p).unwrap(), text);
        assert!(Partial::<PpoConfig>::from_value(serde_json::json!(1)).is_err());
    }
}
