//! The interactive shell (`configurator-cli shell`): a Betaflight-style command line.
//!
//! The user types the same verbs as the one-shot CLI (`get NAME`, `set NAME = VALUE`, `dump`, …)
//! with line editing, tab completion of command and parameter names, and a history kept across
//! sessions. This module knows nothing of the board: it reads lines, splits them into words
//! ([`split_words`]), handles the built-ins (`help`, `exit`, `quit`) and hands every other line to
//! the caller's executor. When stdin is not a terminal (a script piped in), lines are read plainly
//! with no prompt and are not recorded in the history.

use std::fmt::Write as _;
use std::fs::{self, OpenOptions};
use std::io::{self, IsTerminal, Write};
use std::path::{Path, PathBuf};

use rustyline::completion::Completer;
use rustyline::error::ReadlineError;
use rustyline::highlight::Highlighter;
use rustyline::hint::Hinter;
use rustyline::history::MemHistory;
use rustyline::validate::Validator;
use rustyline::{CompletionType, Config, Context, Editor, Helper};

/// One command the shell knows: its name, a one-line usage (`set NAME = VALUE`) and help text.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct CommandHelp {
    /// The first word of the command line.
    pub name: &'static str,
    /// How to call it, e.g. `set NAME = VALUE`.
    pub usage: &'static str,
    /// What it does, in one line.
    pub help: &'static str,
}

/// The built-in commands, handled by the shell itself and never passed to the executor.
const BUILTINS: [CommandHelp; 2] = [
    CommandHelp {
        name: "help",
        usage: "help [COMMAND]",
        help: "list the commands, or explain one",
    },
    CommandHelp { name: "exit", usage: "exit | quit", help: "leave the shell (also Ctrl-D)" },
];

/// What the shell completes: command names, and parameter names after the commands listed in
/// `takes_parameter`.
#[derive(Debug, Clone, Default)]
pub struct Vocabulary {
    /// The commands the executor understands (the built-ins `help`/`exit`/`quit` are added).
    pub commands: Vec<CommandHelp>,
    /// The parameter names, offered after the commands of `takes_parameter`.
    pub parameters: Vec<String>,
    /// The commands whose first argument is a parameter name ([`Vocabulary::new`]: `get`, `set`).
    pub takes_parameter: Vec<&'static str>,
}

impl Vocabulary {
    /// A vocabulary whose `get` and `set` take a parameter name.
    pub fn new(commands: Vec<CommandHelp>, parameters: Vec<String>) -> Self {
        Self { commands, parameters, takes_parameter: vec!["get", "set"] }
    }

    /// The executor's commands then the built-ins (a built-in the executor also lists is shown once).
    fn all_commands(&self) -> impl Iterator<Item = &CommandHelp> {
        let builtin = |c: &&CommandHelp| BUILTINS.iter().any(|b| b.name == c.name);
        self.commands.iter().filter(move |c| !builtin(c)).chain(BUILTINS.iter())
    }
}

/// What the executor (or a built-in) says after a line.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Next {
    /// Read the next line.
    Continue,
    /// Leave the shell.
    Exit,
}

/// A line that cannot be split into words.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum SplitError {
    /// A quote opened at byte `position` is never closed.
    #[error("unterminated {quote} quote starting at column {}", position + 1)]
    UnterminatedQuote { quote: char, position: usize },
}

/// Splits a line into words.
///
/// Words are separated by whitespace; `"…"` and `'…'` group (no escapes inside); `#` at the start
/// of a word outside quotes starts a comment. For `set`, the first unquoted `=` is a word of its
/// own (`set a=1` and `set a = 1` both give `["set", "a", "=", "1"]`) and everything after it is
/// one value word: words joined by a comma are glued (`1, 2, 3` gives `1,2,3`), others keep one
/// space (`My Quad`).
pub fn split_words(line: &str) -> Result<Vec<String>, SplitError> {
    let mut words: Vec<String> = Vec::new();
    let mut word = String::new();
    let mut in_word = false;
    let mut quote: Option<(char, usize)> = None;
    let mut equals_at = None;
    for (i, c) in line.char_indices() {
        match (quote, c) {
            (Some((q, _)), c) if c == q => quote = None,
            (Some(_), c) => word.push(c),
            (None, '"' | '\'') => (quote, in_word) = (Some((c, i)), true),
            (None, '#') if !in_word => break,
            (None, c) if c.is_whitespace() || c == '=' && splits_equals(&words, equals_at) => {
                if in_word {
                    words.push(std::mem::take(&mut word));
                    in_word = false;
                }
                if c == '=' {
                    equals_at = Some(words.len());
                    words.push("=".into());
                }
            }
            (None, c) => {
                in_word = true;
                word.push(c);
            }
        }
    }
    if let Some((quote, position)) = quote {
        return Err(SplitError::UnterminatedQuote { quote, position });
    }
    if in_word {
        words.push(word);
    }
    if let Some(at) = equals_at.filter(|&at| words.len() > at + 2) {
        let value = words.split_off(at + 1).into_iter().reduce(|mut value, next| {
            if !value.ends_with(',') && !next.starts_with(',') {
                value.push(' ');
            }
            value + &next
        });
        words.extend(value);
    }
    Ok(words)
}

/// Whether an unquoted `=` is a word of its own: the first one on a `set` line.
fn splits_equals(words: &[String], equals_at: Option<usize>) -> bool {
    equals_at.is_none() && words.first().is_some_and(|w| w == "set")
}

/// Completes the word before `pos` in `line`: returns where the word starts and the candidates,
/// sorted (prefix match, ASCII case-insensitive).
///
/// The first word completes against the command names (built-ins included); the second against
/// the parameter names after a command of [`Vocabulary::takes_parameter`], against the command
/// names after `help`; anything else has no candidates.
pub fn complete(vocabulary: &Vocabulary, line: &str, pos: usize) -> (usize, Vec<String>) {
    let before = &line[..pos];
    let start = before.rfind(char::is_whitespace).map_or(0, |i| i + 1);
    let prefix = &before[start..];
    let previous: Vec<&str> = before[..start].split_whitespace().collect();
    let command_names = || vocabulary.all_commands().map(|c| c.name).chain(["quit"]);
    let names: Vec<&str> = match previous.as_slice() {
        [] => command_names().collect(),
        ["help"] => command_names().collect(),
        [command] if vocabulary.takes_parameter.contains(command) => {
            vocabulary.parameters.iter().map(String::as_str).collect()
        }
        _ => Vec::new(),
    };
    let lowercase = prefix.to_ascii_lowercase();
    let mut candidates: Vec<String> = names
        .into_iter()
        .filter(|name| name.to_ascii_lowercase().starts_with(&lowercase))
        .map(String::from)
        .collect();
    candidates.sort();
    candidates.dedup();
    (start, candidates)
}

/// The help text: every command's usage and help, aligned (`topic: None`), or one command's.
/// An unknown topic gives an error message.
pub fn help_text(vocabulary: &Vocabulary, topic: Option<&str>) -> Result<String, String> {
    let topic = topic.map(|t| if t == "quit" { "exit" } else { t });
    let shown: Vec<&CommandHelp> =
        vocabulary.all_commands().filter(|c| topic.is_none_or(|t| t == c.name)).collect();
    if shown.is_empty() {
        return Err(format!("no command `{}`: type `help` for the list", topic.unwrap_or("")));
    }
    let width = shown.iter().map(|c| c.usage.len()).max().unwrap_or(0);
    let mut text = String::new();
    for c in shown {
        let _ = writeln!(text, "  {:width$}  {}", c.usage, c.help);
    }
    Ok(text)
}

/// Handles one line: built-ins here, everything else to `execute`. Built-in output goes to `out`,
/// the shell's own errors (bad quoting, unknown help topic) to `err`.
pub fn handle_line(
    vocabulary: &Vocabulary,
    line: &str,
    execute: &mut impl FnMut(&[String]) -> Next,
    out: &mut dyn Write,
    err: &mut dyn Write,
) -> Next {
    let words = match split_words(line) {
        Ok(words) => words,
        Err(e) => {
            let _ = writeln!(err, "error: {e}");
            return Next::Continue;
        }
    };
    match words.first().map(String::as_str) {
        None => Next::Continue,
        Some("exit" | "quit") => Next::Exit,
        Some("help") => {
            match help_text(vocabulary, words.get(1).map(String::as_str)) {
                Ok(text) => _ = write!(out, "{text}"),
                Err(message) => _ = writeln!(err, "{message}"),
            }
            Next::Continue
        }
        Some(_) => execute(&words),
    }
}

/// The default history file, in the user's data directory (on Linux
/// `~/.local/share/configurator-cli/shell-history`); `None` when there is no home directory.
pub fn default_history_path() -> Option<PathBuf> {
    directories::ProjectDirs::from("", "", "configurator-cli")
        .map(|dirs| dirs.data_dir().join("shell-history"))
}

/// How many history lines are loaded; the file is trimmed to this when it grows twice as long.
const HISTORY_LENGTH: usize = 1000;

/// Runs the shell until `exit`, `quit` or Ctrl-D (end of input).
///
/// `execute` gets each line split into words (see [`split_words`]), never empty and never a
/// built-in, and prints its own output and errors. `history` is read at start and appended after
/// each interactive line; its directory is created, and failures are warnings on stderr. Ctrl-C
/// abandons the current line. Only a terminal failure ends the shell with an error.
pub fn run(
    vocabulary: &Vocabulary,
    history: Option<&Path>,
    prompt: &str,
    mut execute: impl FnMut(&[String]) -> Next,
) -> Result<(), ReadlineError> {
    let config = Config::builder()
        .completion_type(CompletionType::List)
        .max_history_size(HISTORY_LENGTH)?
        .auto_add_history(false)
        .build();
    let memory = MemHistory::with_config(&config);
    let mut editor = Editor::with_history(config, memory)?;
    editor.set_helper(Some(ShellHelper { vocabulary }));
    let interactive = io::stdin().is_terminal();
    let mut history = history.filter(|_| interactive);
    if let Some(path) = history {
        for line in load_history(path) {
            editor.add_history_entry(line)?;
        }
    }
    loop {
        let line = match editor.readline(prompt) {
            Ok(line) => line,
            Err(ReadlineError::Interrupted) => {
                eprintln!("(type exit or press Ctrl-D to leave)");
                continue;
            }
            Err(ReadlineError::Eof) => return Ok(()),
            Err(e) => return Err(e),
        };
        let entry = line.trim_end();
        if interactive && !entry.is_empty() && editor.add_history_entry(entry)? {
            if let Some(path) = history {
                if let Err(e) = append_history(path, entry) {
                    eprintln!("warning: cannot write the history {}: {e}", path.display());
                    history = None;
                }
            }
        }
        let next =
            handle_line(vocabulary, &line, &mut execute, &mut io::stdout(), &mut io::stderr());
        if next == Next::Exit {
            return Ok(());
        }
    }
}

/// The last [`HISTORY_LENGTH`] lines of the history file (none if it does not exist yet),
/// trimming the file when it has grown past twice that.
fn load_history(path: &Path) -> Vec<String> {
    let text = match fs::read_to_string(path) {
        Ok(text) => text,
        Err(e) if e.kind() == io::ErrorKind::NotFound => String::new(),
        Err(e) => {
            eprintln!("warning: cannot read the history {}: {e}", path.display());
            String::new()
        }
    };
    let lines: Vec<String> =
        text.lines().filter(|l| !l.trim().is_empty()).map(String::from).collect();
    let kept = lines[lines.len().saturating_sub(HISTORY_LENGTH)..].to_vec();
    if lines.len() > 2 * HISTORY_LENGTH {
        if let Err(e) = fs::write(path, kept.iter().map(|l| l.clone() + "\n").collect::<String>()) {
            eprintln!("warning: cannot trim the history {}: {e}", path.display());
        }
    }
    kept
}

/// Appends one line to the history file, creating it and its directory if needed.
fn append_history(path: &Path, line: &str) -> io::Result<()> {
    if let Some(parent) = path.parent() {
        fs::create_dir_all(parent)?;
    }
    writeln!(OpenOptions::new().create(true).append(true).open(path)?, "{line}")
}

/// The rustyline helper: completion from the [`Vocabulary`]; no hints, highlighting or validation.
struct ShellHelper<'v> {
    vocabulary: &'v Vocabulary,
}

impl Completer for ShellHelper<'_> {
    type Candidate = String;

    fn complete(
        &self,
        line: &str,
        pos: usize,
        _: &Context<'_>,
    ) -> rustyline::Result<(usize, Vec<String>)> {
        let (start, mut candidates) = complete(self.vocabulary, line, pos);
        if let [only] = candidates.as_mut_slice() {
            only.push(' ');
        }
        Ok((start, candidates))
    }
}

impl Hinter for ShellHelper<'_> {
    type Hint = String;
}
impl Highlighter for ShellHelper<'_> {}
impl Validator for ShellHelper<'_> {}
impl Helper for ShellHelper<'_> {}

#[cfg(test)]
mod tests {
    use super::*;

    fn vocabulary() -> Vocabulary {
        let command = |name, usage, help| CommandHelp { name, usage, help };
        Vocabulary::new(
            vec![
                command("get", "get NAME", "show a parameter"),
                command("set", "set NAME = VALUE", "change a parameter"),
                command("save", "save", "write the parameters to flash"),
                command("status", "status", "show the board's state"),
                command("dump", "dump", "print every parameter"),
            ],
            ["rate_roll", "rate_pitch", "motor_idle", "rc_map"].map(String::from).to_vec(),
        )
    }

    fn words(line: &str) -> Vec<String> {
        split_words(line).unwrap()
    }

    #[test]
    fn completes_command_prefixes() {
        let v = vocabulary();
        assert_eq!(complete(&v, "s", 1), (0, vec!["save".into(), "set".into(), "status".into()]));
        assert_eq!(complete(&v, "  he", 4), (2, vec!["help".to_string()]));
        assert_eq!(complete(&v, "q", 1), (0, vec!["quit".to_string()]));
        assert_eq!(complete(&v, "", 0).1.len(), 8);
    }

    #[test]
    fn completes_parameters_after_get_and_set() {
        let v = vocabulary();
        assert_eq!(complete(&v, "set ra", 6), (4, vec!["rate_pitch".into(), "rate_roll".into()]));
        assert_eq!(complete(&v, "get RATE_R", 10), (4, vec!["rate_roll".to_string()]));
        assert_eq!(complete(&v, "set m", 5).1, ["motor_idle"]);
        // The cursor decides: completing `st` at the start of `st rate`.
        assert_eq!(complete(&v, "st rate", 2), (0, vec!["status".to_string()]));
        assert_eq!(complete(&v, "help d", 6), (5, vec!["dump".to_string()]));
    }

    #[test]
    fn completes_nothing_after_unknown_command_or_value() {
        let v = vocabulary();
        assert_eq!(complete(&v, "frobnicate ra", 13), (11, vec![]));
        assert_eq!(complete(&v, "save r", 6).1, Vec::<String>::new());
        assert_eq!(complete(&v, "set rate_roll = r", 17).1, Vec::<String>::new());
        assert_eq!(complete(&v, "xyz", 3).1, Vec::<String>::new());
    }

    #[test]
    fn splits_words_quotes_and_comments() {
        assert_eq!(words("  get   rate_roll  "), ["get", "rate_roll"]);
        assert_eq!(words(r#"apply "my file.json" 'a b'"#), ["apply", "my file.json", "a b"]);
        assert_eq!(words(r#"a"b c"d """#), ["ab cd", ""]);
        assert_eq!(words("dump # everything"), ["dump"]);
        assert_eq!(words("# only a comment"), Vec::<String>::new());
        assert_eq!(words("get a#b '#c'"), ["get", "a#b", "#c"]);
    }

    #[test]
    fn splits_set_around_equals_and_joins_arrays() {
        let expected = ["set", "a", "=", "1"];
        for line in ["set a=1", "set a = 1", "set a =1", "set a= 1"] {
            assert_eq!(words(line), expected, "{line}");
        }
        assert_eq!(words("set rc_map = 1,2,3"), ["set", "rc_map", "=", "1,2,3"]);
        assert_eq!(words("set rc_map = 1, 2 ,3"), ["set", "rc_map", "=", "1,2,3"]);
        assert_eq!(words("set name = My Quad"), ["set", "name", "=", "My Quad"]);
        assert_eq!(words("set s = 'x=y' = z"), ["set", "s", "=", "x=y = z"]);
        assert_eq!(words("set a ="), ["set", "a", "="]);
        assert_eq!(words("get a=1"), ["get", "a=1"]);
    }

    #[test]
    fn unterminated_quote_is_an_error() {
        let error = split_words(r#"set name = "My Quad"#).unwrap_err();
        assert_eq!(error, SplitError::UnterminatedQuote { quote: '"', position: 11 });
        assert!(error.to_string().contains("column 12"));
    }

    #[test]
    fn help_lists_every_command_aligned() {
        let v = vocabulary();
        let text = help_text(&v, None).unwrap();
        assert_eq!(text.lines().count(), v.commands.len() + BUILTINS.len());
        // Each command on its own line, every help text starting in the same column.
        let columns: Vec<usize> = (v.commands.iter().chain(&BUILTINS))
            .map(|c| {
                let line = text.lines().find(|l| l.starts_with(&format!("  {} ", c.usage)));
                line.and_then(|l| l.find(c.help)).unwrap_or_else(|| panic!("{c:?} in {text}"))
            })
            .collect();
        assert!(columns.iter().all(|&c| c == "  set NAME = VALUE  ".len()), "{text}");
        assert_eq!(help_text(&v, Some("set")).unwrap(), "  set NAME = VALUE  change a parameter\n");
        assert!(help_text(&v, Some("quit")).unwrap().contains("leave the shell"));
        assert!(help_text(&v, Some("nope")).unwrap_err().contains("no command `nope`"));
    }

    #[test]
    fn handle_line_runs_builtins_and_passes_the_rest() {
        let v = vocabulary();
        let mut seen = Vec::new();
        let mut execute = |words: &[String]| {
            seen.push(words.to_vec());
            if words[0] == "save" {
                Next::Exit
            } else {
                Next::Continue
            }
        };
        let (mut out, mut err) = (Vec::new(), Vec::new());
        let mut handle = |line| handle_line(&v, line, &mut execute, &mut out, &mut err);
        assert_eq!(handle("set a = 1"), Next::Continue);
        assert_eq!(handle("   # nothing"), Next::Continue);
        assert_eq!(handle("help get"), Next::Continue);
        assert_eq!(handle("help bogus"), Next::Continue);
        assert_eq!(handle("get 'oops"), Next::Continue);
        assert_eq!(handle("save"), Next::Exit);
        assert_eq!(handle("quit"), Next::Exit);
        assert_eq!(handle("exit"), Next::Exit);
        assert_eq!(seen, [vec!["set", "a", "=", "1"], vec!["save"]]);
        assert_eq!(String::from_utf8(out).unwrap(), "  get NAME  show a parameter\n");
        let err = String::from_utf8(err).unwrap();
        assert!(
            err.contains("no command `bogus`") && err.contains("unterminated ' quote"),
            "{err}"
        );
    }

    #[test]
    fn history_file_is_created_appended_and_reloaded() {
        let dir = std::env::temp_dir().join(format!("shell-history-test-{}", std::process::id()));
        let path = dir.join("nested").join("shell-history");
        assert!(load_history(&path).is_empty());
        append_history(&path, "get rate_roll").unwrap();
        append_history(&path, "set a = 1").unwrap();
        assert_eq!(load_history(&path), ["get rate_roll", "set a = 1"]);
        fs::remove_dir_all(dir).unwrap();
    }
}
