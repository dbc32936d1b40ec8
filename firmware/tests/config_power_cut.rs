//! Power cuts during `save`: at every flash step of a save (every word programmed, every sector
//! erase), over a sequence of saves long enough for the store to fill and recycle its sectors,
//! the board is rebooted and must load exactly the old or the new configuration: never a mix,
//! never the defaults, and the next save must work.
//!
//! The flash model is the H743's, made small: 32-byte words programmed once per erase, sectors
//! erased whole. A cut while a word is programmed leaves it with some of its new bytes and an
//! ECC code that no longer matches: reading it is an error (on the board a bus fault, which the
//! board's driver reports as an error). A cut during an erase leaves the sector partly erased,
//! with a torn word at the boundary.

use embedded_storage::nor_flash::{
    ErrorType, NorFlash, NorFlashError, NorFlashErrorKind, ReadNorFlash,
};
use firmware::app::params::{Param, SPECS};
use firmware::app::{Params, Settings};
use flight::rng::Rng;
use protocol::ConfigOrigin;

const WORD: usize = 32;
/// Small sectors, so a few saves fill one and the store must erase and move on.
const SECTOR: usize = 4096;
const SECTORS: usize = 3;

#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum FlashError {
    NotAligned,
    /// A torn word (ECC mismatch) was read.
    Ecc,
    /// The power is off.
    PoweredDown,
    NotErased,
}

impl NorFlashError for FlashError {
    fn kind(&self) -> NorFlashErrorKind {
        match self {
            Self::NotAligned => NorFlashErrorKind::NotAligned,
            _ => NorFlashErrorKind::Other,
        }
    }
}

#[derive(Clone)]
struct SimFlash {
    bytes: Vec<u8>,
    /// Words whose ECC no longer matches their content.
    torn: Vec<bool>,
    /// Flash steps (words programmed, sectors erased) left before the power goes; `None`: no
    /// cut planned.
    steps_left: Option<usize>,
    /// Steps taken since the counter was last reset.
    steps: usize,
    powered: bool,
    /// Whether the power went during an erase.
    cut_in_erase: bool,
    rng: Rng,
}

impl SimFlash {
    fn new(seed: u64) -> Self {
        Self {
            bytes: vec![0xFF; SECTOR * SECTORS],
            torn: vec![false; SECTOR * SECTORS / WORD],
            steps_left: None,
            steps: 0,
            powered: true,
            cut_in_erase: false,
            rng: Rng::new(seed),
        }
    }

    /// Take one step; `false` when the power goes at this step.
    fn step(&mut self) -> bool {
        self.steps += 1;
        match &mut self.steps_left {
            Some(0) => {
                self.powered = false;
                false
            }
            Some(left) => {
                *left -= 1;
                true
            }
            None => true,
        }
    }

    fn below(&mut self, n: usize) -> usize {
        (self.rng.next_u64() % n as u64) as usize
    }
}

impl ErrorType for SimFlash {
    type Error = FlashError;
}

impl ReadNorFlash for SimFlash {
    const READ_SIZE: usize = 1;

    fn read(&mut self, offset: u32, bytes: &mut [u8]) -> Result<(), FlashError> {
        if !self.powered {
            return Err(FlashError::PoweredDown);
        }
        let offset = offset as usize;
        let words = offset / WORD..(offset + bytes.len()).div_ceil(WORD);
        if self.torn[words].iter().any(|&t| t) {
            return Err(FlashError::Ecc);
        }
        bytes.copy_from_slice(&self.bytes[offset..offset + bytes.len()]);
        Ok(())
    }

    fn capacity(&self) -> usize {
        self.bytes.len()
    }
}

impl NorFlash for SimFlash {
    const WRITE_SIZE: usize = WORD;
    const ERASE_SIZE: usize = SECTOR;

    fn erase(&mut self, from: u32, to: u32) -> Result<(), FlashError> {
        let (from, to) = (from as usize, to as usize);
        if !from.is_multiple_of(SECTOR) || !to.is_multiple_of(SECTOR) {
            return Err(FlashError::NotAligned);
        }
        if !self.powered {
            return Err(FlashError::PoweredDown);
        }
        for sector in (from..to).step_by(SECTOR) {
            if !self.step() {
                // Partly erased: a prefix of the sector, then one torn word.
                self.cut_in_erase = true;
                let erased_words = self.below(SECTOR / WORD);
                let end = sector + erased_words * WORD;
                self.bytes[sector..end].fill(0xFF);
                self.torn[sector / WORD..end / WORD].fill(false);
                self.torn[end / WORD] = true;
                return Err(FlashError::PoweredDown);
            }
            self.bytes[sector..sector + SECTOR].fill(0xFF);
            self.torn[sector / WORD..(sector + SECTOR) / WORD].fill(false);
        }
        Ok(())
    }

    fn write(&mut self, offset: u32, bytes: &[u8]) -> Result<(), FlashError> {
        let offset = offset as usize;
        if !offset.is_multiple_of(WORD) || !bytes.len().is_multiple_of(WORD) {
            return Err(FlashError::NotAligned);
        }
        if !self.powered {
            return Err(FlashError::PoweredDown);
        }
        for (i, word) in bytes.chunks(WORD).enumerate() {
            let at = offset + i * WORD;
            if self.bytes[at..at + WORD].iter().any(|&b| b != 0xFF) || self.torn[at / WORD] {
                return Err(FlashError::NotErased);
            }
            if !self.step() {
                // Some of the new bits made it, and the ECC code does not match.
                let written = self.below(WORD + 1);
                self.bytes[at..at + written].copy_from_slice(&word[..written]);
                self.torn[at / WORD] = true;
                return Err(FlashError::PoweredDown);
            }
            self.bytes[at..at + WORD].copy_from_slice(word);
        }
        Ok(())
    }
}

const RANGE: core::ops::Range<u32> = 0..(SECTOR * SECTORS) as u32;

/// A configuration differing from the defaults in a few random parameters.
fn random_config(rng: &mut Rng) -> Params {
    let mut params = Params::default();
    for _ in 0..4 {
        let index = (rng.next_u64() % SPECS.len() as u64) as usize;
        let spec = &SPECS[index];
        let values: Vec<f32> = (0..spec.len)
            .map(|_| {
                let x = spec.min + (spec.max - spec.min) * rng.uniform() as f32;
                match spec.kind {
                    protocol::ParamKind::Real => x,
                    _ => x.round().clamp(spec.min, spec.max),
                }
            })
            .collect();
        params.set(index, &values).unwrap();
    }
    params
}

/// Boot on `flash`, put `config` in force and save it.
fn save(flash: SimFlash, config: &Params) -> (Result<(), protocol::StorageStage>, SimFlash) {
    let mut settings = Settings::load(flash, RANGE);
    settings.update(|params| *params = *config);
    let result = settings.save();
    (result, settings.into_flash().unwrap())
}

/// Power back on and boot: what is in force.
fn reboot(mut flash: SimFlash) -> (Params, ConfigOrigin, SimFlash) {
    flash.powered = true;
    flash.steps_left = None;
    let settings = Settings::load(flash, RANGE);
    let (params, origin) = (*settings.params(), settings.status().origin);
    (params, origin, settings.into_flash().unwrap())
}

#[test]
fn a_power_cut_at_any_step_of_a_save_leaves_the_old_or_the_new_configuration() {
    let mut rng = Rng::new(0x5eed_c0de);
    let mut flash = SimFlash::new(1);
    let mut old = random_config(&mut rng);
    let (result, saved) = save(flash, &old);
    assert_eq!(result, Ok(()));
    flash = saved;
    let (mut cuts, mut kept_old, mut got_new, mut erase_cuts) = (0usize, 0usize, 0usize, 0usize);
    let mut saves = 0;
    while cuts < 1200 {
        let new = random_config(&mut rng);
        // How many flash steps this save takes from this state.
        let mut probe = flash.clone();
        probe.steps = 0;
        let (result, probe) = save(probe, &new);
        assert_eq!(result, Ok(()));
        let steps = probe.steps;
        for cut in 0..steps {
            let mut trial = flash.clone();
            trial.steps = 0;
            trial.steps_left = Some(cut);
            trial.rng = Rng::new(rng.next_u64());
            let (result, trial) = save(trial, &new);
            assert!(result.is_err(), "the save cannot succeed without power (cut {cut}/{steps})");
            erase_cuts += usize::from(trial.cut_in_erase);
            let (loaded, origin, trial) = reboot(trial);
            assert_eq!(origin, ConfigOrigin::Loaded, "cut {cut}/{steps} of save {saves}");
            if loaded == old {
                kept_old += 1;
            } else if loaded == new {
                got_new += 1;
            } else {
                panic!(
                    "cut {cut}/{steps} of save {saves}: neither the old nor the new configuration"
                );
            }
            cuts += 1;
            // Every fourth cut: the store still works after it.
            if cut % 4 == 0 {
                let next = random_config(&mut rng);
                let (result, trial) = save(trial, &next);
                assert_eq!(result, Ok(()), "a save after the cut at {cut}/{steps}");
                assert_eq!(reboot(trial).0, next);
            }
        }
        // The save completes; its configuration is the old one of the next round.
        flash = probe;
        old = new;
        saves += 1;
        assert_eq!(reboot(flash.clone()).0, old);
    }
    println!(
        "{cuts} power cuts over {saves} saves ({erase_cuts} during a sector erase): {kept_old} \
         kept the old configuration, {got_new} had the new one"
    );
    // The last word a save programs is its commit point: every cut comes before it.
    assert_eq!(kept_old + got_new, cuts);
    assert!(
        erase_cuts >= 5,
        "the store recycled sectors during the cuts ({erase_cuts} erase cuts)"
    );
}

#[test]
fn an_unknown_layout_loads_the_defaults_and_leaves_the_bytes_until_save() {
    use firmware::app::settings::ConfigFlash;
    use sequential_storage::cache::Cache;
    use sequential_storage::map::{MapConfig, MapStorage};
    // A newer firmware stored layout 9 under the configuration's key (0).
    let mut map = MapStorage::<u8, _, _>::new(
        ConfigFlash(SimFlash::new(2)),
        MapConfig::new(RANGE),
        Cache::new_uncached(),
    );
    let newer: &[u8] = &[9, 0, 1, 0, 42, 42, 42];
    let mut buffer = [0u8; 256];
    embassy_futures::block_on(map.store_item(&mut buffer, &0u8, &newer)).unwrap();
    let flash = map.destroy().0 .0;
    let before = flash.bytes.clone();
    let settings = Settings::load(flash, RANGE);
    assert_eq!(settings.status().origin, ConfigOrigin::UnknownLayout { version: 9 });
    assert_eq!(*settings.params(), Params::default());
    let flash = settings.into_flash().unwrap();
    assert_eq!(flash.bytes, before, "loading wrote nothing");
    // Until a save, which replaces it.
    let mut settings = Settings::load(flash, RANGE);
    settings.set("throw_momentum_mps", &[6.0]).unwrap();
    settings.save().unwrap();
    assert_eq!(settings.status().origin, ConfigOrigin::Loaded);
    let (params, origin, _) = reboot(settings.into_flash().unwrap());
    assert_eq!((params.scalar(Param::ThrowMomentumMps), origin), (6.0, ConfigOrigin::Loaded));
}

#[test]
fn a_save_refused_by_the_flash_changes_nothing_in_force() {
    let mut flash = SimFlash::new(3);
    flash.steps_left = Some(3);
    let mut settings = Settings::load(flash, RANGE);
    settings.set("gravity_mps2", &[9.79]).unwrap();
    assert_eq!(settings.save(), Err(protocol::StorageStage::Write));
    assert_eq!(settings.params().scalar(Param::GravityMps2), 9.79);
    assert!(settings.status().unsaved_changes);
}

#[test]
fn the_link_key_survives_a_restart_beside_the_parameters_and_neither_disturbs_the_other() {
    let key = [0xA5; protocol::signing::KEY_LEN];
    let mut settings = Settings::load(SimFlash::new(4), RANGE);
    settings.set("throw_momentum_mps", &[6.0]).unwrap();
    settings.save().unwrap();
    settings.set_link_key(Some(key)).unwrap();
    let mut settings = Settings::load(settings.into_flash().unwrap(), RANGE);
    assert!(settings.link_guard().paired(), "paired after a restart");
    assert_eq!(settings.params().scalar(Param::ThrowMomentumMps), 6.0, "parameters kept");
    // A later save and a reset of the parameters leave the key; unpairing leaves the parameters.
    settings.reset();
    settings.save().unwrap();
    let mut settings = Settings::load(settings.into_flash().unwrap(), RANGE);
    assert!(settings.link_guard().paired());
    settings.set("throw_momentum_mps", &[5.0]).unwrap();
    settings.save().unwrap();
    settings.set_link_key(None).unwrap();
    let settings = Settings::load(settings.into_flash().unwrap(), RANGE);
    assert!(!settings.link_guard().paired(), "unpaired after a restart");
    assert_eq!(settings.params().scalar(Param::ThrowMomentumMps), 5.0);
}
