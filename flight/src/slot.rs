//! Storage for a value built in place: its `build_in` writes every field through a pointer into
//! the slot, so that an estimator of tens of kilobytes is never built on a stack and moved. The
//! board's tasks share about 80 KB of stack; built by value and moved, the IMU-offset
//! calibration alone took 52 KB of it (its value and the temporaries of its construction).

use core::mem::MaybeUninit;
use core::ptr::addr_of_mut;

/// A `T` built in place, or nothing yet.
pub struct Slot<T> {
    value: MaybeUninit<T>,
    built: bool,
}

impl<T> Slot<T> {
    /// Nothing built (nothing is constructed).
    pub const fn empty() -> Self {
        // Overwriting a built value in place must leak nothing.
        const { assert!(!core::mem::needs_drop::<T>()) };
        Self { value: MaybeUninit::uninit(), built: false }
    }

    /// An empty slot written in place: only its flag (the storage needs no initialisation).
    ///
    /// # Safety
    /// `this` must be valid for writes and aligned (a field of a value being built in place).
    pub unsafe fn init_empty(this: *mut Self) {
        const { assert!(!core::mem::needs_drop::<T>()) };
        addr_of_mut!((*this).built).write(false);
    }

    /// Build a value in place with `build_in`, replacing any earlier one; on an error the slot
    /// is empty. `build_in` must have written every field of the value when it returns `Ok`.
    pub fn build_with<E>(
        &mut self,
        build_in: impl FnOnce(&mut MaybeUninit<T>) -> Result<&mut T, E>,
    ) -> Result<&mut T, E> {
        self.built = false;
        build_in(&mut self.value)?;
        self.built = true;
        // SAFETY: `build_in` returned `Ok`: every field is written.
        Ok(unsafe { self.value.assume_init_mut() })
    }

    /// The value, once built.
    pub fn get(&self) -> Option<&T> {
        // SAFETY: `built` is set only after `build_in` wrote every field.
        self.built.then(|| unsafe { self.value.assume_init_ref() })
    }

    /// The value, once built.
    pub fn get_mut(&mut self) -> Option<&mut T> {
        // SAFETY: as in `get`.
        self.built.then(|| unsafe { self.value.assume_init_mut() })
    }
}

impl<T: core::fmt::Debug> core::fmt::Debug for Slot<T> {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        f.debug_struct("Slot").field("value", &self.get()).finish()
    }
}
