//! Command-line values checked where clap parses them, so a bad one is one line naming the flag
//! and nothing (a run directory, a process) is made before it is refused.

/// Worker process counts: 1 to 256.
pub fn workers(s: &str) -> Result<usize, String> {
    match s.parse::<usize>() {
        Ok(n) if (1..=256).contains(&n) => Ok(n),
        Ok(n) => Err(format!("{n} is not in 1..=256")),
        Err(e) => Err(e.to_string()),
    }
}

/// Durations in seconds: finite and above zero.
pub fn seconds(s: &str) -> Result<f64, String> {
    match s.parse::<f64>() {
        Ok(v) if v.is_finite() && v > 0.0 => Ok(v),
        Ok(v) => Err(format!("{v} is not a positive number of seconds")),
        Err(e) => Err(e.to_string()),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn bad_values_are_refused_with_the_reason() {
        assert_eq!(workers("4"), Ok(4));
        assert!(workers("0").unwrap_err().contains("1..=256"));
        assert!(workers("-1").is_err());
        assert_eq!(seconds("2.5"), Ok(2.5));
        assert!(seconds("-1").unwrap_err().contains("positive"));
        assert!(seconds("0").is_err() && seconds("nan").is_err() && seconds("inf").is_err());
    }
}
