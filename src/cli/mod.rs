//! Subcommands of the `irlgrid` binary, one module each.

pub mod analyze;
pub mod client;
pub mod coordinator;
pub mod evaluate;
pub mod holdout;
pub mod ops;
pub mod optimize;
pub mod posterior_args;
pub mod resample;
pub mod run;
pub mod sample;
pub mod simulate;
pub mod synth_subjects;
pub mod tables;
pub mod train;
pub mod worker;

/// An error caused by the user's input (file, flag or value): exit status 2.
#[derive(Debug, thiserror::Error)]
#[error("{0}")]
pub struct InputError(pub String);

/// The bearer token from `--token` or from the file `--token-file` names
/// (e.g. a Docker or Kubernetes secret mounted under `/run/secrets`):
/// surrounding whitespace is trimmed; an empty token counts as none from the
/// flag and is refused from a file; giving both is refused.
pub fn resolve_token(
    token: Option<&str>,
    file: Option<&std::path::Path>,
) -> Result<Option<String>, InputError> {
    let token = token.map(str::trim).filter(|t| !t.is_empty());
    match (token, file) {
        (Some(_), Some(f)) => Err(InputError(format!(
            "give the token or a token file ({}), not both",
            f.display()
        ))),
        (Some(t), None) => Ok(Some(t.to_string())),
        (None, None) => Ok(None),
        (None, Some(f)) => {
            let text = std::fs::read_to_string(f)
                .map_err(|e| InputError(format!("reading the token file {}: {e}", f.display())))?;
            let t = text.trim();
            if t.is_empty() {
                return Err(InputError(format!(
                    "the token file {} is empty",
                    f.display()
                )));
            }
            Ok(Some(t.to_string()))
        }
    }
}

/// Prints `err` as one line on stderr and returns the exit status: 2 for bad
/// input, 1 for anything else.
pub fn report_error(err: &anyhow::Error) -> i32 {
    eprintln!("error: {err:#}");
    if err.downcast_ref::<InputError>().is_some() {
        2
    } else {
        1
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_token_comes_from_the_flag_or_a_file_but_not_both() {
        let dir = tempfile::tempdir().unwrap();
        let f = dir.path().join("token");
        std::fs::write(&f, "s3cret\n").unwrap();
        assert_eq!(
            resolve_token(None, Some(&f)).unwrap().as_deref(),
            Some("s3cret")
        );
        assert_eq!(
            resolve_token(Some("t"), None).unwrap().as_deref(),
            Some("t")
        );
        assert_eq!(resolve_token(Some(" "), None).unwrap(), None);
        assert!(resolve_token(Some("t"), Some(&f)).is_err());
        std::fs::write(&f, " \n").unwrap();
        assert!(resolve_token(None, Some(&f)).is_err());
        assert!(resolve_token(None, Some(&dir.path().join("missing"))).is_err());
    }
}
