//! The link keys this computer shares with boards (`protocol::signing`), one file per board.
//!
//! `configurator-cli pair` (over USB) draws a key from the operating system's random numbers,
//! gives it to the board and keeps it here, as `<serial>.key` (64 hexadecimal digits, readable
//! by the user only), in the user's configuration directory (on Linux
//! `~/.config/configurator-cli/keys/`), or in the directory named by the environment variable
//! [`KEY_DIR_ENV`]. Whenever the configurator then connects to that board, over any link, it
//! signs what configures, arms, spins or steers the craft with it, so a telemetry radio carries
//! those requests; anybody else on the radio's channel is refused.

use protocol::signing::{LinkKey, KEY_LEN};
use std::path::{Path, PathBuf};

/// The environment variable that names another key directory (tests, several users).
pub const KEY_DIR_ENV: &str = "CONFIGURATOR_KEY_DIR";

/// Why a key could not be read, made or kept.
#[derive(Debug, thiserror::Error)]
pub enum KeyError {
    #[error("no home directory to keep link keys in; set {KEY_DIR_ENV}")]
    NoDirectory,
    #[error("cannot {what} {path}: {source}")]
    Io { what: &'static str, path: PathBuf, source: std::io::Error },
    #[error("{path} is not a link key (64 hexadecimal digits); pair again over USB")]
    Malformed { path: PathBuf },
    #[error("the operating system gave no random numbers for a key: {0}")]
    Random(String),
}

/// The directory the keys are kept in.
pub fn key_dir() -> Result<PathBuf, KeyError> {
    if let Some(dir) = std::env::var_os(KEY_DIR_ENV) {
        return Ok(PathBuf::from(dir));
    }
    directories::ProjectDirs::from("", "", "configurator-cli")
        .map(|dirs| dirs.config_dir().join("keys"))
        .ok_or(KeyError::NoDirectory)
}

/// The key file of the board with serial `serial` (characters other than letters, digits, `-`
/// and `_` become `_`, so a serial cannot name another path).
pub fn key_path(dir: &Path, serial: &str) -> PathBuf {
    let name: String = serial
        .chars()
        .map(|c| if c.is_ascii_alphanumeric() || c == '-' || c == '_' { c } else { '_' })
        .collect();
    dir.join(format!("{name}.key"))
}

/// A fresh key from the operating system's random numbers.
pub fn new_key() -> Result<LinkKey, KeyError> {
    let mut key = [0u8; KEY_LEN];
    getrandom::fill(&mut key).map_err(|e| KeyError::Random(e.to_string()))?;
    Ok(key)
}

/// The key kept for board `serial`, if any.
pub fn load(serial: &str) -> Result<Option<LinkKey>, KeyError> {
    let path = key_path(&key_dir()?, serial);
    let text = match std::fs::read_to_string(&path) {
        Ok(text) => text,
        Err(e) if e.kind() == std::io::ErrorKind::NotFound => return Ok(None),
        Err(source) => return Err(KeyError::Io { what: "read", path, source }),
    };
    parse(text.trim()).map(Some).ok_or(KeyError::Malformed { path })
}

/// Keep `key` for board `serial` (readable and writable by the user only). Returns the path.
pub fn store(serial: &str, key: &LinkKey) -> Result<PathBuf, KeyError> {
    let dir = key_dir()?;
    std::fs::create_dir_all(&dir).map_err(|source| KeyError::Io {
        what: "create",
        path: dir.clone(),
        source,
    })?;
    let path = key_path(&dir, serial);
    let text: String = key.iter().map(|b| format!("{b:02x}")).collect();
    write_private(&path, &text).map_err(|source| KeyError::Io {
        what: "write",
        path: path.clone(),
        source,
    })?;
    Ok(path)
}

/// Forget the key of board `serial` (nothing to do when none is kept).
pub fn forget(serial: &str) -> Result<(), KeyError> {
    let path = key_path(&key_dir()?, serial);
    match std::fs::remove_file(&path) {
        Err(e) if e.kind() != std::io::ErrorKind::NotFound => {
            Err(KeyError::Io { what: "remove", path, source: e })
        }
        _ => Ok(()),
    }
}

fn parse(text: &str) -> Option<LinkKey> {
    if text.len() != 2 * KEY_LEN || !text.is_ascii() {
        return None;
    }
    let mut key = [0u8; KEY_LEN];
    for (i, byte) in key.iter_mut().enumerate() {
        *byte = u8::from_str_radix(&text[2 * i..2 * i + 2], 16).ok()?;
    }
    Some(key)
}

#[cfg(unix)]
fn write_private(path: &Path, text: &str) -> std::io::Result<()> {
    use std::io::Write;
    use std::os::unix::fs::OpenOptionsExt;
    let mut file = std::fs::OpenOptions::new()
        .write(true)
        .create(true)
        .truncate(true)
        .mode(0o600)
        .open(path)?;
    file.write_all(text.as_bytes())
}

#[cfg(not(unix))]
fn write_private(path: &Path, text: &str) -> std::io::Result<()> {
    std::fs::write(path, text)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_key_reads_back_as_written_and_a_damaged_file_is_a_typed_error() {
        let key = new_key().unwrap();
        assert_ne!(key, new_key().unwrap(), "two draws differ");
        let text: String = key.iter().map(|b| format!("{b:02x}")).collect();
        assert_eq!(parse(&text), Some(key));
        assert_eq!(parse(&text[1..]), None);
        assert_eq!(parse(&text.replace(&text[..2], "zz")), None);
    }

    #[test]
    fn a_serial_cannot_name_another_path() {
        let path = key_path(Path::new("/keys"), "../../etc/passwd");
        assert_eq!(path, Path::new("/keys/______etc_passwd.key"));
    }
}
