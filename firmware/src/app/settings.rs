//! The configuration in force and its copy in flash.
//!
//! [`Settings`] holds the parameter values ([`Params`]) and, when the board has one, a store on
//! NOR flash: `sequential-storage`'s map over any `embedded-storage` [`NorFlash`] (the H743's
//! second bank, the SITL's flash file, a test's memory). The whole configuration is one map item
//! under one key, so a save is one item write: sequential-storage checksums every item and
//! only ever appends, so a power cut at any instant of a save leaves the previous item (the old
//! configuration) or the new one, never a mix. Flash is written only by [`Settings::save`].
//!
//! The item (layout [`LAYOUT_VERSION`]): `version u16, count u16`, then per parameter
//! `name_len u8, name, len u8, len × f32`, all little-endian. Parameters are matched by name, so
//! a firmware that adds or removes a parameter still loads the others; a stored value that is
//! now out of range or of another length takes its default and is counted. An unknown layout
//! version loads nothing: the defaults are in force, the status says so, and the stored bytes
//! stay untouched until the next save.
//!
//! The H743's flash has ECC: a word torn by a power cut while it was programmed raises a bus
//! fault when the CPU reads it, so the board's flash driver must read the configuration pages in
//! a way that reports such a word as an error instead. [`ConfigFlash`] turns every word that
//! cannot be read into zeros, which the item checksums then reject: a torn word is a torn item.

use super::params::{self, Params, PARAM_COUNT, SPECS};
use super::StatusView;
use core::ops::Range;
use embedded_storage::nor_flash::NorFlash;
use flight::learner::FlightPhase;
use protocol::signing::{LinkKey, Signature, KEY_LEN};
use protocol::{ConfigOrigin, ConfigStatus, DeviceError, ImuOffsetSource, StorageStage};
use sequential_storage::cache::{Cache, Uncached};
use sequential_storage::map::{MapConfig, MapStorage};

/// Layout version of the stored configuration this firmware writes and reads.
pub const LAYOUT_VERSION: u16 = 1;
/// The map key of the configuration item.
const CONFIG_KEY: u8 = 0;
/// The map key of the link key item ([`protocol::signing`]): the key's 32 bytes, or none when
/// unpaired. Kept apart from the parameters so that no dump, diff or reset ever shows or
/// touches it.
const LINK_KEY_KEY: u8 = 1;
/// Largest encoded configuration, bytes (the registry today needs 1.3 KiB, with 256 bytes to
/// spare: tested).
pub const MAX_CONFIG_BYTES: usize = 2048;
/// sequential-storage's work buffer: the item (key and value) rounded up to flash words (the
/// H743 writes 32-byte words).
const BUFFER_LEN: usize = MAX_CONFIG_BYTES + 64;

/// A blocking [`NorFlash`] seen through `embedded-storage-async` (what sequential-storage
/// takes), with unreadable words read as zeros (see the module documentation).
pub struct ConfigFlash<F>(pub F);

impl<F: NorFlash> embedded_storage_async::nor_flash::ErrorType for ConfigFlash<F> {
    type Error = F::Error;
}

impl<F: NorFlash> embedded_storage_async::nor_flash::ReadNorFlash for ConfigFlash<F> {
    const READ_SIZE: usize = F::READ_SIZE;

    async fn read(&mut self, offset: u32, bytes: &mut [u8]) -> Result<(), Self::Error> {
        if self.0.read(offset, bytes).is_ok() {
            return Ok(());
        }
        // Word by word: the words that read are kept, the others are torn.
        let word = F::WRITE_SIZE.max(F::READ_SIZE);
        let mut at = 0;
        while at < bytes.len() {
            let address = offset as usize + at;
            let end = (at + word - address % word).min(bytes.len());
            if self.0.read(address as u32, &mut bytes[at..end]).is_err() {
                bytes[at..end].fill(0);
            }
            at = end;
        }
        Ok(())
    }

    fn capacity(&self) -> usize {
        self.0.capacity()
    }
}

impl<F: NorFlash> embedded_storage_async::nor_flash::NorFlash for ConfigFlash<F> {
    const WRITE_SIZE: usize = F::WRITE_SIZE;
    const ERASE_SIZE: usize = F::ERASE_SIZE;

    async fn erase(&mut self, from: u32, to: u32) -> Result<(), Self::Error> {
        self.0.erase(from, to)
    }

    async fn write(&mut self, offset: u32, bytes: &[u8]) -> Result<(), Self::Error> {
        self.0.write(offset, bytes)
    }
}

/// The flash of a board without a configuration store ([`Settings::without_store`]'s type
/// where one is needed): no capacity, every operation refused.
#[derive(Clone, Copy, Debug, Default)]
pub struct NoFlash;

impl embedded_storage::nor_flash::ErrorType for NoFlash {
    type Error = embedded_storage::nor_flash::NorFlashErrorKind;
}

impl embedded_storage::nor_flash::ReadNorFlash for NoFlash {
    const READ_SIZE: usize = 1;

    fn read(&mut self, _offset: u32, _bytes: &mut [u8]) -> Result<(), Self::Error> {
        Err(embedded_storage::nor_flash::NorFlashErrorKind::OutOfBounds)
    }

    fn capacity(&self) -> usize {
        0
    }
}

impl NorFlash for NoFlash {
    const WRITE_SIZE: usize = 1;
    const ERASE_SIZE: usize = 1;

    fn erase(&mut self, _from: u32, _to: u32) -> Result<(), Self::Error> {
        Err(embedded_storage::nor_flash::NorFlashErrorKind::OutOfBounds)
    }

    fn write(&mut self, _offset: u32, _bytes: &[u8]) -> Result<(), Self::Error> {
        Err(embedded_storage::nor_flash::NorFlashErrorKind::OutOfBounds)
    }
}

/// The configuration store on flash.
struct Store<F: NorFlash> {
    map: MapStorage<u8, ConfigFlash<F>, Cache<Uncached, Uncached, Uncached, u8>>,
}

impl<F: NorFlash> Store<F> {
    /// Item `key`'s bytes copied into `out`, or `None` when nothing is stored under it.
    fn load(
        &mut self,
        key: u8,
        buffer: &mut [u8],
        out: &mut [u8],
    ) -> Result<Option<usize>, StorageStage> {
        let item = embassy_futures::block_on(self.map.fetch_item::<&[u8]>(buffer, &key))
            .map_err(|_| StorageStage::Read)?;
        match item {
            None => Ok(None),
            Some(bytes) if bytes.len() <= out.len() => {
                out[..bytes.len()].copy_from_slice(bytes);
                Ok(Some(bytes.len()))
            }
            Some(_) => Err(StorageStage::TooLarge),
        }
    }

    fn save(&mut self, key: u8, buffer: &mut [u8], bytes: &[u8]) -> Result<(), StorageStage> {
        embassy_futures::block_on(self.map.store_item(buffer, &key, &bytes))
            .map_err(|_| StorageStage::Write)
    }
}

/// What guards the untrusted links ([`protocol::signing`]), shared by every link of the board:
/// the paired key and this start-up's session. Each link keeps its own last timestamp (as
/// MAVLink keeps one per stream), so two signers on two links never refuse each other's
/// requests in flight.
#[derive(Clone, Copy, Default)]
pub struct LinkGuard {
    key: Option<LinkKey>,
    session: u64,
}

/// How a signed request fared against the [`LinkGuard`].
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum SignatureCheck {
    /// The frame carried no signature.
    Unsigned,
    /// The paired key's MAC over this session, with a timestamp greater than any before.
    Accepted,
    /// No key is paired, or the MAC is another key's or another session's.
    BadSignature,
    /// A valid MAC whose timestamp is not greater than the last accepted one.
    Replayed { last_timestamp: u64 },
}

impl LinkGuard {
    /// Check `signature` against the link's `last_timestamp` and, when it is accepted, raise
    /// that to its own.
    pub fn check(
        &self,
        signature: Option<&Signature<'_>>,
        last_timestamp: &mut u64,
    ) -> SignatureCheck {
        let Some(signature) = signature else { return SignatureCheck::Unsigned };
        let Some(key) = &self.key else { return SignatureCheck::BadSignature };
        if !signature.verify(key, self.session) {
            return SignatureCheck::BadSignature;
        }
        if signature.timestamp <= *last_timestamp {
            return SignatureCheck::Replayed { last_timestamp: *last_timestamp };
        }
        *last_timestamp = signature.timestamp;
        SignatureCheck::Accepted
    }

    /// Whether a key is paired.
    pub fn paired(&self) -> bool {
        self.key.is_some()
    }

    /// This start-up's session.
    pub fn session(&self) -> u64 {
        self.session
    }
}

impl core::fmt::Debug for LinkGuard {
    /// Never prints the key.
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        f.debug_struct("LinkGuard")
            .field("paired", &self.paired())
            .field("session", &self.session)
            .finish()
    }
}

/// The configuration in force, and where it came from.
pub struct Settings<F: NorFlash> {
    params: Params,
    /// What the flash holds (or the defaults, when it holds nothing we can read).
    stored: Params,
    store: Option<Store<F>>,
    origin: ConfigOrigin,
    rejected_at_load: u16,
    saves: u32,
    /// Counts changes to `params`: the application reapplies them when it moves.
    generation: u32,
    /// The generation last handed to the other tasks ([`Settings::service`]).
    applied_generation: Option<u32>,
    /// `LearnedModel::samples` of the identification last stored.
    absorbed_samples: Option<u32>,
    /// The link key (loaded from its own item) and the signing state.
    guard: LinkGuard,
    buffer: [u8; BUFFER_LEN],
}

impl<F: NorFlash> Settings<F> {
    /// Load the configuration from `flash` within `range` (whole erase pages, at least two), or
    /// start from the defaults. Never fails: what cannot be loaded is reported in the status.
    pub fn load(flash: F, range: Range<u32>) -> Self {
        let mut settings = Self::without_store();
        let Ok(config) = MapConfig::try_new(range) else {
            return settings;
        };
        let mut store =
            Store { map: MapStorage::new(ConfigFlash(flash), config, Cache::new_uncached()) };
        let mut key = [0u8; KEY_LEN];
        if let Ok(Some(KEY_LEN)) = store.load(LINK_KEY_KEY, &mut settings.buffer, &mut key) {
            settings.guard.key = Some(key);
        }
        let mut bytes = [0u8; MAX_CONFIG_BYTES];
        settings.origin = match store.load(CONFIG_KEY, &mut settings.buffer, &mut bytes) {
            Ok(None) => ConfigOrigin::Defaults,
            Ok(Some(len)) => match decode(&bytes[..len]) {
                Ok((params, rejected)) => {
                    settings.params = params;
                    settings.stored = params;
                    settings.rejected_at_load = rejected;
                    ConfigOrigin::Loaded
                }
                Err(Undecodable::Layout(version)) => ConfigOrigin::UnknownLayout { version },
                Err(Undecodable::Malformed) => ConfigOrigin::Unreadable,
            },
            Err(_) => ConfigOrigin::Unreadable,
        };
        settings.store = Some(store);
        settings
    }

    /// Settings of a board without a configuration store: changes last until power-off.
    pub fn without_store() -> Self {
        Self {
            params: Params::default(),
            stored: Params::default(),
            store: None,
            origin: ConfigOrigin::NoStore,
            rejected_at_load: 0,
            saves: 0,
            generation: 0,
            applied_generation: None,
            absorbed_samples: None,
            guard: LinkGuard::default(),
            buffer: [0; BUFFER_LEN],
        }
    }

    /// The values in force.
    pub fn params(&self) -> &Params {
        &self.params
    }

    /// Set parameter `name` (validated as a whole; nothing changes on an error).
    pub fn set(&mut self, name: &str, values: &[f32]) -> Result<usize, DeviceError> {
        let index = params::find(name.as_bytes())
            .ok_or_else(|| DeviceError::UnknownParam { name: protocol::text(name) })?;
        if self.params.set(index, values)? {
            self.generation = self.generation.wrapping_add(1);
        }
        Ok(index)
    }

    /// Change the values in force through `change` (calibration and identification results).
    pub fn update(&mut self, change: impl FnOnce(&mut Params)) {
        let before = self.params;
        change(&mut self.params);
        if self.params != before {
            self.generation = self.generation.wrapping_add(1);
        }
    }

    /// The link task's housekeeping after its passes: a finished identification's results go
    /// into the parameters (to be saved by the user), and when the values in force changed since
    /// the last call (or on the first call) they are returned, for the board to hand to the
    /// control step (`ControlSettings`) and the background task (`Background::configure`).
    pub fn service(&mut self, view: &StatusView) -> Option<Params> {
        let learned = &view.background.learned;
        let finished = view.control.phase == FlightPhase::Done
            && learned.thrust_axis.is_some()
            && self.absorbed_samples != Some(learned.samples);
        if finished {
            self.absorbed_samples = Some(learned.samples);
            self.update(|params| params.store_learned(learned));
            // An IMU offset fitted in this flight (and flown: usable) is stored as a
            // calibration would be, with its 95 % ellipsoid: the next identifications use it,
            // and `save` keeps it. Not one fitted on speeds modelled from the commands (no
            // speed telemetry): the modelled speeds' errors are not in its ellipsoid (the truth
            // inside it in 71 % of 1,000 random worlds, docs/algorithms/imu-offset.md), so it
            // is flown and shown, and the next flight fits its own.
            let background = &view.background;
            if background.learner_offset == ImuOffsetSource::FittedInFlight
                && background.imu_offset_fitted_in_flight
                && !learned.speeds_modelled
            {
                let offset = &background.imu_offset;
                self.update(|p| p.store_calibration(offset.r_imu_m, offset.ci95_semi_axes_m, None));
            }
        }
        if self.applied_generation == Some(self.generation) {
            return None;
        }
        self.applied_generation = Some(self.generation);
        Some(self.params)
    }

    /// Every parameter back to its default (in force now; stored by the next save).
    pub fn reset(&mut self) {
        self.update(|params| *params = Params::default());
    }

    /// Write the values in force to flash. On an error nothing in force changed and the flash
    /// still holds the previous configuration.
    pub fn save(&mut self) -> Result<(), StorageStage> {
        let Some(store) = self.store.as_mut() else {
            return Err(StorageStage::NoStore);
        };
        let mut bytes = [0u8; MAX_CONFIG_BYTES];
        let len = encode(&self.params, &mut bytes).ok_or(StorageStage::TooLarge)?;
        store.save(CONFIG_KEY, &mut self.buffer, &bytes[..len])?;
        self.stored = self.params;
        self.saves = self.saves.wrapping_add(1);
        if matches!(self.origin, ConfigOrigin::UnknownLayout { .. } | ConfigOrigin::Unreadable) {
            self.origin = ConfigOrigin::Loaded;
        }
        Ok(())
    }

    /// The signing state every link checks signed requests against.
    pub fn link_guard(&self) -> &LinkGuard {
        &self.guard
    }

    /// This start-up's signing session: a number the board draws at start-up (a hardware random
    /// number), so that frames signed before a restart fail after it.
    pub fn set_link_session(&mut self, session: u64) {
        self.guard.session = session;
    }

    /// Pair (`Some`) or unpair (`None`): written to flash at once (an empty item unpairs), in
    /// force only once written; without a store, in force until power-off.
    pub fn set_link_key(&mut self, key: Option<LinkKey>) -> Result<(), StorageStage> {
        if let Some(store) = self.store.as_mut() {
            let bytes = key.as_ref().map_or(&[][..], |key| &key[..]);
            store.save(LINK_KEY_KEY, &mut self.buffer, bytes)?;
        }
        self.guard.key = key;
        Ok(())
    }

    /// The store's state (the link adds whether a calibration or motor test runs).
    pub fn status(&self) -> ConfigStatus {
        ConfigStatus {
            origin: self.origin,
            layout_version: LAYOUT_VERSION,
            param_count: PARAM_COUNT as u16,
            unsaved_changes: self.params != self.stored,
            rejected_at_load: self.rejected_at_load,
            saves: self.saves,
            calibrating: false,
            motor_test: false,
        }
    }

    /// Give the flash back (tests and the SITL's restart).
    pub fn into_flash(self) -> Option<F> {
        self.store.map(|store| store.map.destroy().0 .0)
    }
}

/// Why stored bytes did not become a configuration.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum Undecodable {
    Layout(u16),
    Malformed,
}

/// Encode `params` into `out`; `None` when it does not fit.
fn encode(params: &Params, out: &mut [u8]) -> Option<usize> {
    let mut writer = Writer { out, at: 0 };
    writer.put(&LAYOUT_VERSION.to_le_bytes())?;
    writer.put(&(PARAM_COUNT as u16).to_le_bytes())?;
    for (index, spec) in SPECS.iter().enumerate() {
        writer.put(&[spec.name.len() as u8])?;
        writer.put(spec.name.as_bytes())?;
        writer.put(&[spec.len as u8])?;
        for value in params.values(index) {
            writer.put(&value.to_le_bytes())?;
        }
    }
    Some(writer.at)
}

struct Writer<'a> {
    out: &'a mut [u8],
    at: usize,
}

impl Writer<'_> {
    fn put(&mut self, bytes: &[u8]) -> Option<()> {
        self.out.get_mut(self.at..self.at + bytes.len())?.copy_from_slice(bytes);
        self.at += bytes.len();
        Some(())
    }
}

/// Decode stored bytes: the parameters (defaults where absent) and how many stored values were
/// refused.
fn decode(bytes: &[u8]) -> Result<(Params, u16), Undecodable> {
    let mut reader = Reader { bytes, at: 0 };
    let version = u16::from_le_bytes(reader.take_array().ok_or(Undecodable::Malformed)?);
    if version != LAYOUT_VERSION {
        return Err(Undecodable::Layout(version));
    }
    let count = u16::from_le_bytes(reader.take_array().ok_or(Undecodable::Malformed)?);
    let mut params = Params::default();
    let mut rejected = 0u16;
    for _ in 0..count {
        let name_len = usize::from(reader.take(1).ok_or(Undecodable::Malformed)?[0]);
        let name = reader.take(name_len).ok_or(Undecodable::Malformed)?;
        let len = usize::from(reader.take(1).ok_or(Undecodable::Malformed)?[0]);
        let mut values = [0f32; protocol::PARAM_MAX_LEN];
        let stored = values.get_mut(..len).ok_or(Undecodable::Malformed)?;
        for value in stored.iter_mut() {
            *value = f32::from_le_bytes(reader.take_array().ok_or(Undecodable::Malformed)?);
        }
        // A parameter this firmware no longer has is ignored; one it refuses keeps its default.
        let index = params::find(name);
        if let Some(index) = index {
            if params.set(index, stored).is_err() {
                rejected = rejected.saturating_add(1);
            }
        }
    }
    if reader.at != bytes.len() {
        return Err(Undecodable::Malformed);
    }
    Ok((params, rejected))
}

struct Reader<'a> {
    bytes: &'a [u8],
    at: usize,
}

impl<'a> Reader<'a> {
    fn take(&mut self, n: usize) -> Option<&'a [u8]> {
        let slice = self.bytes.get(self.at..self.at + n)?;
        self.at += n;
        Some(slice)
    }

    fn take_array<const N: usize>(&mut self) -> Option<[u8; N]> {
        self.take(N)?.try_into().ok()
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::app::params::Param;

    /// A finished identification whose IMU offset was fitted in flight (usable, flown), its
    /// speeds measured or modelled from the commands.
    fn finished_with_fitted_offset(speeds_modelled: bool) -> StatusView {
        use crate::app::background::BackgroundResults;
        use flight::learner::{LearnedModel, LearnedThrustAxis};
        let mut background = BackgroundResults::default();
        background.learned = LearnedModel {
            thrust_axis: Some(LearnedThrustAxis::default()),
            samples: 900,
            speeds_modelled,
            ..background.learned
        };
        background.learner_offset = ImuOffsetSource::FittedInFlight;
        background.imu_offset_fitted_in_flight = true;
        background.imu_offset.r_imu_m = [0.01, -0.02, 0.005];
        background.imu_offset.ci95_semi_axes_m = [0.004, 0.002, 0.001];
        let control =
            crate::app::control::ControlSnapshot { phase: FlightPhase::Done, ..Default::default() };
        StatusView {
            control,
            background,
            step_time: None,
            board: Default::default(),
            gnss: None,
            compass: None,
        }
    }

    #[test]
    fn an_offset_fitted_on_measured_speeds_is_stored_and_one_on_modelled_speeds_is_not() {
        let mut settings = Settings::<NoFlash>::without_store();
        settings.service(&finished_with_fitted_offset(false));
        assert_eq!(settings.params().configured_offset_m(), Some([0.01, -0.02, 0.005]));
        // Without speed telemetry the fit's ellipsoid leaves out the modelled speeds' errors:
        // flown in that flight, not stored for the next (which fits its own).
        let mut settings = Settings::<NoFlash>::without_store();
        settings.service(&finished_with_fitted_offset(true));
        let stored = settings.params().configured_offset_m();
        assert!(stored.is_none(), "{stored:?}");
    }

    #[test]
    fn the_whole_registry_fits_the_store_with_room_to_grow() {
        let mut bytes = [0u8; MAX_CONFIG_BYTES];
        let len = encode(&Params::default(), &mut bytes).unwrap();
        println!("configuration: {len} bytes of {MAX_CONFIG_BYTES}");
        assert!(len + 256 <= MAX_CONFIG_BYTES, "{len} bytes");
    }

    #[test]
    fn encoding_round_trips_and_matches_by_name() {
        let mut params = Params::default();
        params.set(Param::ImuOffsetM as usize, &[0.011, -0.022, 0.033]).unwrap();
        params.set(Param::ThrowMomentumMps as usize, &[5.5]).unwrap();
        let mut bytes = [0u8; MAX_CONFIG_BYTES];
        let len = encode(&params, &mut bytes).unwrap();
        assert_eq!(decode(&bytes[..len]), Ok((params, 0)));
        // The layout version is the first two bytes; another one loads nothing.
        let mut other = bytes;
        other[..2].copy_from_slice(&7u16.to_le_bytes());
        assert_eq!(decode(&other[..len]), Err(Undecodable::Layout(7)));
        assert_eq!(decode(&bytes[..len - 1]), Err(Undecodable::Malformed));
    }

    #[test]
    fn a_stored_value_now_out_of_range_takes_its_default_and_is_counted() {
        let mut params = Params::default();
        params.set(Param::ThrowMomentumMps as usize, &[9.0]).unwrap();
        params.set(Param::GravityMps2 as usize, &[9.79]).unwrap();
        let mut bytes = [0u8; MAX_CONFIG_BYTES];
        let len = encode(&params, &mut bytes).unwrap();
        // Patch the stored momentum to 11 m/s (outside 2..10).
        let name = b"throw_momentum_mps";
        let at = bytes.windows(name.len()).position(|w| w == name).unwrap() + name.len() + 1;
        bytes[at..at + 4].copy_from_slice(&11f32.to_le_bytes());
        let (loaded, rejected) = decode(&bytes[..len]).unwrap();
        assert_eq!(rejected, 1);
        assert_eq!(loaded.scalar(Param::ThrowMomentumMps), 4.0);
        assert_eq!(loaded.scalar(Param::GravityMps2), 9.79);
    }
}
