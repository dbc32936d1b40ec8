//! The board's parameters on the host: `get`, `set`, `dump`, `diff` and `apply`, Betaflight's
//! way.
//!
//! A `dump` lists every parameter as a `set NAME = VALUE` line, each after a comment giving its
//! meaning, unit, range and default; a `diff` lists only those that differ from their default.
//! Either can be pasted back with `apply`: comments and blank lines are tolerated, every line is
//! checked against the board's own descriptions before anything is sent (the first bad line
//! stops it, with its line number, and nothing changes), then the lines are applied as one
//! batch. Should the board still refuse one, those already applied are put back. Nothing is
//! saved by `apply`: `save` does that.
//!
//! Values print in the shortest form that reads back to the same `f32`, so
//! `diff` → `defaults` → `apply` → `dump` gives back the very same text.

use crate::link::{Client, LinkError};
use protocol::{
    text as bounded, ParamInfo, ParamKind, ParamRef, ParamValues, Reply, Request, SetParam,
};
use std::fmt::Write as _;

/// Every parameter of the board, in registry order.
pub fn fetch_all(client: &mut Client) -> Result<Vec<ParamInfo>, LinkError> {
    let first = fetch(client, ParamRef::Index(0))?;
    let mut all = vec![first];
    for index in 1..all[0].count {
        all.push(fetch(client, ParamRef::Index(index))?);
    }
    Ok(all)
}

/// One parameter, by index or name.
pub fn fetch(client: &mut Client, reference: ParamRef) -> Result<ParamInfo, LinkError> {
    match client.request(&Request::GetParam(reference), "the parameter request")? {
        Reply::Param(info) => Ok(info),
        other => Err(LinkError::Unexpected(format!("{other:?} to the parameter request"))),
    }
}

/// Set one parameter; the board's answer is the value now in force.
pub fn set(client: &mut Client, name: &str, values: &[f32]) -> Result<ParamInfo, LinkError> {
    let request = Request::SetParam(SetParam {
        name: bounded(name),
        values: ParamValues::from_slice(values).unwrap_or_default(),
    });
    match client.request(&request, "the set request")? {
        Reply::Param(info) => Ok(info),
        other => Err(LinkError::Unexpected(format!("{other:?} to the set request"))),
    }
}

/// Values as `a,b,c`, each in the shortest form that reads back to the same `f32`.
pub fn format_values(values: &[f32]) -> String {
    values.iter().map(|v| v.to_string()).collect::<Vec<_>>().join(",")
}

/// The unit in brackets with the range, e.g. `[m, -0.5 to 0.5]`.
fn range_text(info: &ParamInfo) -> String {
    let kind = match info.kind {
        ParamKind::Real => "",
        ParamKind::Integer => "whole, ",
        ParamKind::Flag => "flag, ",
    };
    let unit = if info.unit.is_empty() { String::new() } else { format!("{}, ", info.unit) };
    format!("[{kind}{unit}{} to {}]", info.min, info.max)
}

/// One parameter for `get`: name, value, unit, range, default and help.
pub fn describe(info: &ParamInfo) -> String {
    let learned = if info.learned { ", learned" } else { "" };
    format!(
        "{} = {}\n  {} {}{learned}; default {}\n",
        info.name,
        format_values(&info.value),
        info.help,
        range_text(info),
        format_values(&info.default),
    )
}

/// `dump` (every parameter) or `diff` (only those not at their default), as `set` lines.
pub fn listing(params: &[ParamInfo], only_changed: bool, header: &str) -> String {
    let mut out = String::new();
    let _ = writeln!(out, "# {header}");
    let mut shown = 0;
    for info in params {
        if only_changed && info.value == info.default {
            continue;
        }
        shown += 1;
        let learned = if info.learned { " (learned)" } else { "" };
        let _ = writeln!(out, "# {}{learned} {}", info.help, range_text(info));
        let _ = writeln!(out, "set {} = {}", info.name, format_values(&info.value));
    }
    if only_changed && shown == 0 {
        let _ = writeln!(out, "# every parameter is at its default");
    }
    out
}

/// One line of a file given to `apply`, checked.
#[derive(Debug, Clone, PartialEq)]
pub struct Assignment {
    /// Line number in the file, from 1.
    pub line: usize,
    pub name: String,
    pub values: Vec<f32>,
}

/// Why `apply` refused a file: the first bad line.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
#[error("line {line}: {message}; nothing was applied")]
pub struct ApplyError {
    pub line: usize,
    pub message: String,
}

/// Parse `NAME = VALUE` (or `NAME=VALUE`) words after `set`, arrays comma-separated.
pub fn parse_assignment(words: &[&str]) -> Result<(String, Vec<f32>), String> {
    let joined = words.join(" ");
    let (name, value) = joined
        .split_once('=')
        .ok_or_else(|| format!("expected `set NAME = VALUE`, got `set {joined}`"))?;
    let name = name.trim();
    if name.is_empty() || name.contains(char::is_whitespace) {
        return Err(format!("expected one parameter name before `=`, got `{name}`"));
    }
    let values = parse_values(value.trim())?;
    Ok((name.to_string(), values))
}

/// Comma-separated numbers.
pub fn parse_values(text: &str) -> Result<Vec<f32>, String> {
    if text.is_empty() {
        return Err("no value after `=`".into());
    }
    text.split(',')
        .map(|field| {
            let field = field.trim();
            field
                .parse::<f32>()
                .ok()
                .filter(|v| v.is_finite())
                .ok_or_else(|| format!("`{field}` is not a finite number"))
        })
        .collect()
}

/// Check `values` against the board's description of the parameter.
pub fn check(info: &ParamInfo, values: &[f32]) -> Result<(), String> {
    if values.len() != info.value.len() {
        return Err(format!(
            "{} takes {} value{} (comma-separated), not {}",
            info.name,
            info.value.len(),
            if info.value.len() == 1 { "" } else { "s" },
            values.len()
        ));
    }
    for &value in values {
        if matches!(info.kind, ParamKind::Integer | ParamKind::Flag) && value.fract() != 0.0 {
            return Err(format!("{} takes whole numbers, not {value}", info.name));
        }
        if !(value >= info.min && value <= info.max) {
            let unit = if info.unit.is_empty() { String::new() } else { format!(" {}", info.unit) };
            return Err(format!(
                "{} = {value}{unit} is outside the allowed range {} to {}{unit}",
                info.name, info.min, info.max
            ));
        }
    }
    Ok(())
}

/// Parse and check a pasted `dump` or `diff` against the board's parameters.
pub fn parse_apply(text: &str, params: &[ParamInfo]) -> Result<Vec<Assignment>, ApplyError> {
    let mut out = Vec::new();
    for (index, raw) in text.lines().enumerate() {
        let line = index + 1;
        let fail = |message: String| ApplyError { line, message };
        let content = raw.split_once('#').map_or(raw, |(before, _)| before).trim();
        let content = content.trim_start_matches('\u{feff}');
        if content.is_empty() {
            continue;
        }
        let words: Vec<&str> = content.split_whitespace().collect();
        if words[0] != "set" {
            return Err(fail(format!("expected `set NAME = VALUE`, got `{content}`")));
        }
        let (name, values) = parse_assignment(&words[1..]).map_err(fail)?;
        let info = params
            .iter()
            .find(|p| p.name.as_str() == name)
            .ok_or_else(|| fail(format!("no parameter is called `{name}`")))?;
        check(info, &values).map_err(fail)?;
        out.push(Assignment { line, name, values });
    }
    Ok(out)
}

/// Apply checked assignments as one batch: if the board refuses one, the ones already set are
/// put back to their previous values. Returns how many values changed.
pub fn apply(
    client: &mut Client,
    assignments: &[Assignment],
    before: &[ParamInfo],
) -> Result<usize, ApplyError> {
    let mut applied: Vec<&ParamInfo> = Vec::new();
    let mut changed = 0;
    for assignment in assignments {
        let previous = before.iter().find(|p| p.name.as_str() == assignment.name);
        match set(client, &assignment.name, &assignment.values) {
            Ok(_) => {
                if let Some(previous) = previous {
                    changed += usize::from(previous.value.as_slice() != assignment.values);
                    applied.push(previous);
                }
            }
            Err(error) => {
                for previous in applied.iter().rev() {
                    let _ = set(client, &previous.name, &previous.value);
                }
                return Err(ApplyError {
                    line: assignment.line,
                    message: format!("the board refused it ({error})"),
                });
            }
        }
    }
    Ok(changed)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn info(name: &str, kind: ParamKind, len: usize, min: f32, max: f32) -> ParamInfo {
        ParamInfo {
            index: 0,
            count: 2,
            name: bounded(name),
            kind,
            unit: bounded("m"),
            min,
            max,
            default: (0..len).map(|_| 0.0).collect(),
            value: (0..len).map(|_| 0.0).collect(),
            learned: false,
            help: bounded("help"),
        }
    }

    fn board() -> Vec<ParamInfo> {
        vec![
            info("imu_offset_m", ParamKind::Real, 3, -0.5, 0.5),
            info("model_motors", ParamKind::Integer, 1, 0.0, 8.0),
        ]
    }

    #[test]
    fn a_dump_parses_back_to_its_values() {
        let mut params = board();
        params[0].value = ParamValues::from_slice(&[0.012, -0.0041, 0.1 + 0.2]).unwrap();
        let text = listing(&params, false, "dump");
        let parsed = parse_apply(&text, &params).unwrap();
        assert_eq!(parsed.len(), 2);
        assert_eq!(parsed[0].values, params[0].value.as_slice(), "exact f32 round trip");
        assert_eq!(parsed[0].line, 3, "two comment lines come first");
        let diff = listing(&params, true, "diff");
        assert_eq!(parse_apply(&diff, &params).unwrap().len(), 1, "only the changed one");
    }

    #[test]
    fn the_first_bad_line_is_named() {
        let params = board();
        let cases = [
            ("set imu_offset_m = 0,0,0\n\n# ok\nset imu_offset_m = 0,0,0.7\n", 4, "outside"),
            ("set imu_offset_m = 0,0\n", 1, "takes 3 values"),
            ("set model_motors = 2.5\n", 1, "whole numbers"),
            ("set nothing = 1\n", 1, "no parameter is called `nothing`"),
            ("# a\nget imu_offset_m\n", 2, "expected `set NAME = VALUE`"),
            ("set imu_offset_m = 0,x,0\n", 1, "`x` is not a finite number"),
            ("set imu_offset_m 0,0,0\n", 1, "expected `set NAME = VALUE`"),
        ];
        for (text, line, says) in cases {
            let error = parse_apply(text, &params).unwrap_err();
            assert_eq!(error.line, line, "{text:?}");
            assert!(error.message.contains(says), "{text:?}: {}", error.message);
        }
        let ok = parse_apply("set imu_offset_m=0.01, -0.02 ,0 # trailing comment\n", &params);
        assert_eq!(ok.unwrap()[0].values, vec![0.01, -0.02, 0.0]);
    }
}
