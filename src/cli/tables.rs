//! Text tables of a result document that more than one subcommand prints:
//! `irlgrid run` under its summary, `irlgrid score` alone.

use shared::analysis::{Method, ResultDocument};

/// The inferred value of each subject by every method, with the
/// posterior's credible set and out-of-model flag ("" without subjects).
pub fn subject_table(doc: &ResultDocument) -> String {
    let mut out = String::new();
    if doc.subjects.is_empty() {
        return out;
    }
    let mut values: Vec<f64> = doc.weights.iter().map(|w| w.value).collect();
    values.sort_by(f64::total_cmp);
    values.dedup();
    let lowest = values.first().copied().unwrap_or(0.0);
    let highest = values.last().copied().unwrap_or(0.0);
    // One column per method; the posterior adds its credible set.
    let mut head = format!("\n{:<28}", "subject");
    for m in Method::ALL {
        head.push_str(&format!(" {:>22}", format!("inferred ({})", m.title())));
    }
    head.push_str(&format!(
        "  {:<20} {}\n",
        "90 % credible set", "out of model"
    ));
    out.push_str(&head);
    for s in &doc.subjects {
        let mut line = format!("{:<28}", s.subject);
        for m in Method::ALL {
            line.push_str(&format!(" {:>22}", fmt_opt(s.inferred(m))));
        }
        let post = s.method(Method::Posterior);
        let credible = post.and_then(|p| p.credible_set.as_ref());
        let set = credible.map_or_else(|| "-".to_string(), |c| c.describe());
        let flag = match post.and_then(|p| p.out_of_model.as_ref()) {
            Some(o) if o.flagged => match &o.reason {
                Some(r) => format!("yes (p = {:.1e}; {r})", o.p_value),
                None => format!("yes (p = {:.1e})", o.p_value),
            },
            Some(_) => "no".to_string(),
            None => "-".to_string(),
        };
        // A set that spans the grid says so in words.
        let verdict = credible
            .and_then(|c| c.verdict(values.len(), lowest, highest))
            .map(|v| format!("  ({v})"))
            .unwrap_or_default();
        line.push_str(&format!("  {set:<20} {flag}{verdict}\n"));
        out.push_str(&line);
    }
    out
}

fn fmt_opt(v: Option<f64>) -> String {
    v.map(|x| format!("{x}")).unwrap_or_else(|| "-".to_string())
}
