//! The states the store keeps in its `status` and `refine_state` columns,
//! as Rust reads them: [`shared::api::JobState`] and
//! [`shared::api::SearchState`] (the wire types, whose `as_str` is the
//! stored text) and [`RefineState`]. Code that reads a stored state parses
//! it into its enum and compares enums, never text; SQL binds a state's
//! `as_str` as a parameter and never spells it (`tests/sql_guard.rs`
//! scans for that). The values are the schema's `check` constraints.

/// Where a search's refinement stands (`searches.refine_state`; null for a
/// search that does not refine).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum RefineState {
    /// Rounds to come: the search refines when it next completes.
    Pending,
    /// Refinement has ended; the final document is the search's.
    Settled,
}

impl RefineState {
    /// Every state.
    pub const ALL: [RefineState; 2] = [Self::Pending, Self::Settled];

    /// The stored text.
    pub fn as_str(self) -> &'static str {
        match self {
            Self::Pending => "pending",
            Self::Settled => "settled",
        }
    }

    /// The state of a stored text.
    pub fn parse(s: &str) -> Option<Self> {
        Self::ALL.into_iter().find(|st| st.as_str() == s)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn refine_states_round_trip_their_stored_text() {
        for st in RefineState::ALL {
            assert_eq!(RefineState::parse(st.as_str()), Some(st));
        }
        assert_eq!(RefineState::parse("running"), None);
    }
}
