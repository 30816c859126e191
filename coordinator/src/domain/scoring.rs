//! Scoring new subjects against a search's finished trials without running
//! a job, and saving them with the search: the rules (a converged trial to
//! score against, no subject stored twice, at most
//! [`intake::MAX_SUBJECTS`]) and the scoring itself.

use std::collections::BTreeMap;

use shared::analysis::{
    build_report_from, subjects_to_csv, Identifiability, Observables, ReportOptions, SubjectPath,
};
use shared::api::{ScoreQuery, ScoredSubjects, SubjectsBody};

use super::{search_info, DomainError, DomainResult};
use crate::domain::results;
use crate::intake;
use crate::state::AppState;
use crate::store::queue::{self, SearchInfo};

/// The subjects as sent: a CSV body, or JSON `{"subjects_csv": ...}`.
#[derive(Debug, Clone, Copy)]
pub struct SubjectsUpload<'a> {
    /// The body is JSON (its content type says so).
    pub json: bool,
    /// The body's bytes.
    pub body: &'a [u8],
}

impl SubjectsUpload<'_> {
    /// The subjects' CSV text.
    fn text(self) -> DomainResult<String> {
        if self.json {
            Ok(serde_json::from_slice::<SubjectsBody>(self.body)
                .map_err(|e| DomainError::Invalid(format!("body: {e}")))?
                .subjects_csv)
        } else {
            String::from_utf8(self.body.to_vec())
                .map_err(|_| DomainError::Invalid("subjects_csv: the body is not UTF-8".into()))
        }
    }
}

/// Scores the uploaded subjects against search `id`'s finished trials and,
/// with `q.save`, stores them with the search (its cached facts and
/// document are dropped, so the next read shows them).
pub async fn score_subjects(
    s: &AppState,
    id: &str,
    q: &ScoreQuery,
    upload: SubjectsUpload<'_>,
) -> DomainResult<ScoredSubjects> {
    let info = search_info(s, id).await?;
    let subjects = intake::parse_subjects(&upload.text()?)?;
    let weights = results::digests(s, &info).await?;
    if !weights.iter().flat_map(|w| &w.trials).any(|t| t.converged) {
        return Err(DomainError::Conflict(
            "no grid point has a converged trial yet; score subjects once one has".into(),
        ));
    }
    let mut stored = if q.save {
        kept_with(&info, &subjects)?
    } else {
        Vec::new()
    };
    let report = report_options(&info, q.observables.as_deref())?;
    let points: Vec<BTreeMap<String, f64>> = weights.iter().map(|w| w.params.clone()).collect();
    let (doc, subjects) = tokio::task::spawn_blocking(move || {
        let doc = build_report_from(&weights, &subjects, &report, Identifiability::Never);
        (doc, subjects)
    })
    .await
    .map_err(|e| DomainError::internal(format!("scoring subjects: {e}")))?;
    if q.save {
        stored.extend(subjects);
        queue::set_subjects(&s.db, id, &subjects_to_csv(&stored)).await?;
        s.forget_search(id).await;
        tracing::info!(added = doc.subjects.len(), "subjects added to the search");
    }
    Ok(ScoredSubjects {
        search_id: id.to_string(),
        saved: q.save,
        points,
        subjects: doc.subjects,
        notes: doc.notes,
    })
}

/// The subjects stored with the search, when `new` may join them: none of
/// its names is stored already, and together they stay within
/// [`intake::MAX_SUBJECTS`].
fn kept_with(info: &SearchInfo, new: &[SubjectPath]) -> DomainResult<Vec<SubjectPath>> {
    let stored = info.subjects.clone();
    if let Some(dup) = new
        .iter()
        .find(|n| stored.iter().any(|o| o.subject == n.subject))
    {
        return Err(DomainError::Conflict(format!(
            "subject {:?} is already stored with this search; rename it to add it",
            dup.subject
        )));
    }
    if stored.len() + new.len() > intake::MAX_SUBJECTS {
        return Err(DomainError::Invalid(format!(
            "subjects_csv: {} stored and {} new subjects exceed the limit {}",
            stored.len(),
            new.len(),
            intake::MAX_SUBJECTS
        )));
    }
    Ok(stored)
}

/// The search's report options, with the observables the query names.
fn report_options(info: &SearchInfo, observables: Option<&str>) -> DomainResult<ReportOptions> {
    let mut report = info.resolved.report.clone();
    if let Some(name) = observables {
        report.posterior.observables = Observables::parse(name).ok_or_else(|| {
            DomainError::Invalid(format!(
                "observables: {name:?} is none of {}",
                Observables::ALL.map(|o| o.key()).join(", ")
            ))
        })?;
    }
    Ok(report)
}
