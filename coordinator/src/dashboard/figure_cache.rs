//! The figures part of a search page, rendered once per document.
//!
//! Drawing the five figures (and the per-subject ones) costs far more than
//! the rest of a page, and under load a page is read many times between
//! two changes of its document. So the rendered HTML is kept per search
//! with a stamp of what it was drawn from (the search's state, which
//! document, the refinement); a page whose stamp matches copies the HTML.
//! A completed search's stamp comes from its job counts alone, so its
//! stored document is not even read again.

use std::collections::HashMap;
use std::sync::{Arc, Mutex};

/// Searches whose figures are kept; the least recently read goes first.
/// A figures part is a few hundred KiB at most, so this bounds the cache
/// to a few MiB.
const MAX_ENTRIES: usize = 32;

struct Entry {
    stamp: String,
    html: Arc<str>,
    /// The [`Entries::clock`] of its last read or write.
    read: u64,
}

#[derive(Default)]
struct Entries {
    by_id: HashMap<String, Entry>,
    /// Counts reads and writes: the order in which entries were used.
    clock: u64,
}

/// Rendered figures by search id.
#[derive(Default)]
pub struct FigureCache {
    entries: Mutex<Entries>,
}

impl FigureCache {
    /// The figures of `id` if they were drawn from `stamp`.
    pub fn get(&self, id: &str, stamp: &str) -> Option<Arc<str>> {
        let mut entries = self.entries.lock().unwrap_or_else(|p| p.into_inner());
        entries.clock += 1;
        let now = entries.clock;
        let e = entries.by_id.get_mut(id).filter(|e| e.stamp == stamp)?;
        e.read = now;
        Some(e.html.clone())
    }

    /// Keeps the figures of `id` drawn from `stamp`, making room first.
    pub fn put(&self, id: &str, stamp: String, html: Arc<str>) {
        let mut entries = self.entries.lock().unwrap_or_else(|p| p.into_inner());
        entries.clock += 1;
        let now = entries.clock;
        if !entries.by_id.contains_key(id) && entries.by_id.len() >= MAX_ENTRIES {
            if let Some(oldest) = entries
                .by_id
                .iter()
                .min_by_key(|(_, e)| e.read)
                .map(|(k, _)| k.clone())
            {
                entries.by_id.remove(&oldest);
            }
        }
        entries.by_id.insert(
            id.to_string(),
            Entry {
                stamp,
                html,
                read: now,
            },
        );
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn serves_only_the_stamp_it_was_drawn_from() {
        let c = FigureCache::default();
        assert!(c.get("s", "a").is_none());
        c.put("s", "a".into(), "<p>a</p>".into());
        assert_eq!(c.get("s", "a").as_deref(), Some("<p>a</p>"));
        assert!(c.get("s", "b").is_none(), "another document");
        c.put("s", "b".into(), "<p>b</p>".into());
        assert!(c.get("s", "a").is_none(), "replaced");
        assert_eq!(c.get("s", "b").as_deref(), Some("<p>b</p>"));
    }

    #[test]
    fn holds_at_most_its_bound_and_drops_the_least_recently_read() {
        let c = FigureCache::default();
        for k in 0..MAX_ENTRIES {
            c.put(&format!("s{k}"), "x".into(), "h".into());
        }
        // s0 is read again, so s1 is now the least recently read.
        assert!(c.get("s0", "x").is_some());
        c.put("new", "x".into(), "h".into());
        assert_eq!(c.entries.lock().unwrap().by_id.len(), MAX_ENTRIES);
        assert!(c.get("s0", "x").is_some());
        assert!(c.get("s1", "x").is_none());
        assert!(c.get("new", "x").is_some());
    }
}
