//! Subject trajectory CSV (docs/science.md#subject-data): strict reader and matching writer for
//! the `subject,time,x,z` format. Parses from text; callers do the file I/O.
//!
//! Accepted beyond the bare format: a UTF-8 byte-order mark, CRLF line ends,
//! blank lines anywhere, spaces around fields, and an RFC 4180 quoted subject
//! field (`"a, b"`, with `""` for a quote) so that any name the writer emits
//! reads back. Quoted fields cannot span lines.

use std::collections::HashMap;

use serde::{Deserialize, Serialize};

use super::AnalysisError;

/// The required header line.
pub const SUBJECT_CSV_HEADER: &str = "subject,time,x,z";

/// Fewest samples accepted per subject (the analysis needs 4 distinct points).
const MIN_SAMPLES: usize = 4;

/// One subject's COM trajectory (docs/science.md#subject-data): time in seconds, x forward and z
/// up in metres (any consistent unit works; preprocessing normalizes).
#[derive(Serialize, Deserialize, Clone, Debug, PartialEq)]
pub struct SubjectPath {
    /// Subject label, non-empty. Synthetic subjects must say so (docs/science.md#subject-data).
    pub subject: String,
    /// Sample times, strictly increasing.
    pub t: Vec<f64>,
    /// Forward COM coordinate.
    pub x: Vec<f64>,
    /// Vertical COM coordinate.
    pub z: Vec<f64>,
}

fn csv_err(line: usize, msg: impl Into<String>) -> AnalysisError {
    AnalysisError::Csv {
        line,
        msg: msg.into(),
    }
}

/// Splits one CSV line into trimmed fields, honouring double quotes.
fn split_fields(line: &str) -> Result<Vec<String>, String> {
    let mut fields = Vec::new();
    let mut chars = line.chars().peekable();
    loop {
        while chars.peek().is_some_and(|c| *c == ' ' || *c == '\t') {
            chars.next();
        }
        let mut field = String::new();
        if chars.peek() == Some(&'"') {
            chars.next();
            loop {
                match chars.next() {
                    Some('"') if chars.peek() == Some(&'"') => {
                        chars.next();
                        field.push('"');
                    }
                    Some('"') => break,
                    Some(c) => field.push(c),
                    None => return Err("unterminated quoted field".into()),
                }
            }
            while chars.peek().is_some_and(|c| c.is_whitespace()) {
                chars.next();
            }
            match chars.next() {
                None => {
                    fields.push(field);
                    return Ok(fields);
                }
                Some(',') => fields.push(field),
                Some(c) => return Err(format!("unexpected {c:?} after a quoted field")),
            }
        } else {
            loop {
                match chars.next() {
                    None => {
                        fields.push(field.trim().to_string());
                        return Ok(fields);
                    }
                    Some(',') => break,
                    Some('"') => return Err("a quote inside an unquoted field".into()),
                    Some(c) => field.push(c),
                }
            }
            fields.push(field.trim().to_string());
        }
    }
}

/// Parses a finite number, naming the column in the error.
fn number(line: usize, column: &str, text: &str) -> Result<f64, AnalysisError> {
    match text.parse::<f64>() {
        Ok(v) if v.is_finite() => Ok(v),
        Ok(_) => Err(csv_err(
            line,
            format!("{column} value {text:?} is not a finite number"),
        )),
        Err(_) => Err(csv_err(
            line,
            format!("{column} value {text:?} is not a number"),
        )),
    }
}

/// A subject being read: its path, where it starts, and the previous time
/// as written (for the error message).
struct Open {
    path: SubjectPath,
    first_line: usize,
    last_line: usize,
    last_time_text: String,
}

fn close(open: Open, done: &mut Vec<SubjectPath>) -> Result<(), AnalysisError> {
    let n = open.path.t.len();
    if n < MIN_SAMPLES {
        return Err(csv_err(
            open.first_line,
            format!(
                "subject {:?} has {n} samples (lines {}-{}); at least {MIN_SAMPLES} are needed",
                open.path.subject, open.first_line, open.last_line
            ),
        ));
    }
    done.push(open.path);
    Ok(())
}

/// Reads subject trajectories from CSV text (docs/science.md#subject-data). The first non-blank
/// line must be exactly `subject,time,x,z` (trailing whitespace allowed).
/// Every data row has four fields; numbers are finite; a subject's rows are
/// contiguous, in strictly increasing time, and at least 4. Errors name the
/// 1-based line. Subjects come back in order of first appearance.
pub fn parse_subjects_csv(text: &str) -> Result<Vec<SubjectPath>, AnalysisError> {
    let text = text.strip_prefix('\u{feff}').unwrap_or(text);
    let mut lines = text
        .lines()
        .enumerate()
        .map(|(i, l)| (i + 1, l))
        .filter(|(_, l)| !l.trim().is_empty());
    let Some((header_line, header)) = lines.next() else {
        return Err(csv_err(
            1,
            format!("empty file; expected the header {SUBJECT_CSV_HEADER:?}"),
        ));
    };
    if header.trim_end() != SUBJECT_CSV_HEADER {
        return Err(csv_err(
            header_line,
            format!(
                "expected the header {SUBJECT_CSV_HEADER:?}, found {:?}",
                header.trim_end()
            ),
        ));
    }

    let mut done: Vec<SubjectPath> = Vec::new();
    // Line ranges of finished subjects, to explain a non-contiguous one.
    let mut seen: HashMap<String, (usize, usize)> = HashMap::new();
    let mut open: Option<Open> = None;
    for (line, text) in lines {
        let fields = split_fields(text).map_err(|m| csv_err(line, m))?;
        let [subject, time, x, z] = fields.as_slice() else {
            return Err(csv_err(
                line,
                format!(
                    "expected 4 fields ({SUBJECT_CSV_HEADER}), found {}",
                    fields.len()
                ),
            ));
        };
        if subject.is_empty() {
            return Err(csv_err(line, "empty subject name"));
        }
        let t = number(line, "time", time)?;
        let xv = number(line, "x", x)?;
        let zv = number(line, "z", z)?;

        let continues = open.as_ref().is_some_and(|o| &o.path.subject == subject);
        if !continues {
            // Finish the previous subject first so errors come in line order.
            if let Some(o) = open.take() {
                seen.insert(o.path.subject.clone(), (o.first_line, o.last_line));
                close(o, &mut done)?;
            }
            if let Some((first, last)) = seen.get(subject.as_str()) {
                return Err(csv_err(
                    line,
                    format!(
                        "rows of subject {subject:?} are not contiguous (its earlier rows are lines {first}-{last})"
                    ),
                ));
            }
        }
        let o = open.get_or_insert_with(|| Open {
            path: SubjectPath {
                subject: subject.clone(),
                t: Vec::new(),
                x: Vec::new(),
                z: Vec::new(),
            },
            first_line: line,
            last_line: line,
            last_time_text: String::new(),
        });
        if let Some(&prev) = o.path.t.last() {
            if t <= prev {
                return Err(csv_err(
                    line,
                    format!(
                        "time {time} is not after the previous {} for subject {subject:?}",
                        o.last_time_text
                    ),
                ));
            }
        }
        o.path.t.push(t);
        o.path.x.push(xv);
        o.path.z.push(zv);
        o.last_line = line;
        o.last_time_text.clone_from(time);
    }
    match open {
        Some(o) => close(o, &mut done)?,
        None => {
            return Err(csv_err(
                header_line,
                "no data rows after the header".to_string(),
            ))
        }
    }
    Ok(done)
}

/// Quotes a CSV field when it would not read back as itself; line breaks,
/// which a line-based reader cannot hold, become spaces.
pub(crate) fn csv_field(s: &str) -> String {
    let s = s.replace(['\r', '\n'], " ");
    if s.contains([',', '"']) || s.trim() != s {
        format!("\"{}\"", s.replace('"', "\"\""))
    } else {
        s
    }
}

/// Writes subject trajectories in the format [`parse_subjects_csv`] reads
/// (docs/science.md#subject-data), `\n` line ends, numbers in shortest round-trip form
/// (exponent notation for very large or small magnitudes).
pub fn subjects_to_csv(subjects: &[SubjectPath]) -> String {
    let mut out = format!("{SUBJECT_CSV_HEADER}\n");
    for s in subjects {
        let name = csv_field(&s.subject);
        for ((t, x), z) in s.t.iter().zip(&s.x).zip(&s.z) {
            out.push_str(&format!("{name},{t:?},{x:?},{z:?}\n"));
        }
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    const GOOD: &str = "subject,time,x,z\r\n\
        s1,0.0,0.01,0.60\r\n\
        s1,0.05,0.02,0.70\r\n\
        \r\n\
        s1,0.10,0.02,0.85\r\n\
        s1,0.15,0.01,0.98\r\n\
        \"s 2, synthetic\",0,0,0.6\n\
        \"s 2, synthetic\",1,0.1,0.7\n\
        \"s 2, synthetic\", 2 , 0.1 ,0.8\n\
        \"s 2, synthetic\",3,0,0.9\n";

    fn err_line(text: &str) -> (usize, String) {
        match parse_subjects_csv(text) {
            Err(AnalysisError::Csv { line, msg }) => (line, msg),
            other => panic!("expected a CSV error, got {other:?}"),
        }
    }

    #[test]
    fn good_file_parses_in_first_appearance_order() {
        let s = parse_subjects_csv(GOOD).unwrap();
        assert_eq!(s.len(), 2);
        assert_eq!(s[0].subject, "s1");
        assert_eq!(s[0].t, vec![0.0, 0.05, 0.10, 0.15]);
        assert_eq!(s[0].z, vec![0.60, 0.70, 0.85, 0.98]);
        assert_eq!(s[1].subject, "s 2, synthetic");
        assert_eq!(s[1].x, vec![0.0, 0.1, 0.1, 0.0]);
    }

    #[test]
    fn writer_output_reads_back_identically() {
        let mut s = parse_subjects_csv(GOOD).unwrap();
        s[0].subject = "quote \"q\"".into();
        s[0].x[1] = 0.1 + 0.2; // needs all 17 digits
        let back = parse_subjects_csv(&subjects_to_csv(&s)).unwrap();
        assert_eq!(back, s);
    }

    #[test]
    fn header_with_bom_and_trailing_space_is_accepted() {
        let text = format!("\u{feff}{SUBJECT_CSV_HEADER}  \na,0,0,0\na,1,0,1\na,2,0,2\na,3,0,3\n");
        assert_eq!(parse_subjects_csv(&text).unwrap().len(), 1);
    }

    #[test]
    fn wrong_or_missing_header_is_an_error_on_its_line() {
        let (line, msg) = err_line("\n\nsubject,t,x,z\na,0,0,0\n");
        assert_eq!(line, 3);
        assert!(msg.contains("expected the header"), "{msg}");
        assert_eq!(err_line("").0, 1);
        assert_eq!(err_line("subject,time,x,z\n\n").0, 1);
    }

    #[test]
    fn wrong_field_count_is_an_error_on_its_line() {
        let (line, msg) = err_line("subject,time,x,z\na,0,0,0\na,1,0\n");
        assert_eq!(line, 3);
        assert!(msg.contains("expected 4 fields"), "{msg}");
        assert_eq!(err_line("subject,time,x,z\na,0,0,0,9\n").0, 2);
        assert_eq!(err_line("subject,time,x,z\n\"a,0,0,0\n").0, 2);
    }

    #[test]
    fn bad_or_non_finite_number_is_an_error_on_its_line() {
        let (line, msg) = err_line("subject,time,x,z\na,0,0,0\na,1,zero,1\n");
        assert_eq!(
            (line, msg.as_str()),
            (3, "x value \"zero\" is not a number")
        );
        let (line, msg) = err_line("subject,time,x,z\na,0,0,0\na,1,0,1\na,2,0,NaN\n");
        assert_eq!(line, 4);
        assert!(msg.contains("not a finite number"), "{msg}");
        assert_eq!(err_line("subject,time,x,z\na,inf,0,0\n").0, 2);
        assert_eq!(err_line("subject,time,x,z\n,0,0,0\n").0, 2);
    }

    #[test]
    fn non_increasing_time_is_an_error_on_its_line() {
        let text = "subject,time,x,z\n\
            s1,0,0,0\ns1,1,0,1\ns1,2,0,2\ns1,3,0,3\n\
            s2,0.05,0,0\ns2,0.15,0,1\ns2,0.10,0,2\n";
        assert_eq!(
            err_line(text),
            (
                8,
                "time 0.10 is not after the previous 0.15 for subject \"s2\"".to_string()
            )
        );
        let (line, _) = err_line("subject,time,x,z\na,0,0,0\na,0,0,1\n");
        assert_eq!(line, 3);
    }

    #[test]
    fn non_contiguous_subject_is_an_error_on_its_line() {
        let text = "subject,time,x,z\n\
            a,0,0,0\na,1,0,1\na,2,0,2\na,3,0,3\n\
            b,0,0,0\nb,1,0,1\nb,2,0,2\nb,3,0,3\n\
            a,4,0,4\n";
        let (line, msg) = err_line(text);
        assert_eq!(line, 10);
        assert!(
            msg.contains("not contiguous") && msg.contains("lines 2-5"),
            "{msg}"
        );
    }

    #[test]
    fn subject_with_too_few_samples_is_an_error_at_its_first_line() {
        let text = "subject,time,x,z\n\
            a,0,0,0\na,1,0,1\na,2,0,2\na,3,0,3\n\
            b,0,0,0\nb,1,0,1\nb,2,0,2\n";
        let (line, msg) = err_line(text);
        assert_eq!(line, 6);
        assert!(msg.contains("has 3 samples"), "{msg}");
    }
}
