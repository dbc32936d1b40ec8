//! Restart into the STM32H743's ROM bootloader (USB DFU on PA11/PA12), on the host's request.
//!
//! The link task, once it has sent its reply, calls [`restart_into_bootloader`]: it leaves
//! [`crate::targets::BOOTLOADER_MAGIC`] in a word of DTCM that the start-up code does not
//! initialise (cortex-m-rt's `.uninit` section; SRAM keeps its contents across a system reset)
//! and resets the chip. The very first thing `init` does, before the clocks are touched, is
//! [`take_request`]: if the word holds the magic, it is cleared and [`jump_to_bootloader`] hands
//! the chip, still in its reset state, to the ROM at
//! [`crate::targets::h743::SYSTEM_BOOTLOADER_VECTORS`]. Any other value (a normal reset, RAM
//! noise after power-on) boots the firmware.
//!
//! Only reachable when disarmed: the link refuses `RebootToBootloader` while anything is armed
//! (`DeviceError::RefusedWhileArmed`), and the board announces `Capabilities::BOOTLOADER`.

use crate::targets::{boot_to_bootloader, h743, BOOTLOADER_MAGIC};
use core::mem::MaybeUninit;
use core::ptr::addr_of_mut;
use cortex_m::peripheral::{NVIC, SCB};

#[link_section = ".uninit.BOOT_REQUEST"]
static mut BOOT_REQUEST: MaybeUninit<u32> = MaybeUninit::uninit();

/// Leave the request and reset. Never returns.
pub fn restart_into_bootloader() -> ! {
    // SAFETY: a volatile word write to this module's own `.uninit` static.
    unsafe { core::ptr::write_volatile(addr_of_mut!(BOOT_REQUEST) as *mut u32, BOOTLOADER_MAGIC) };
    cortex_m::asm::dsb();
    SCB::sys_reset()
}

/// Whether the previous run asked for the bootloader (and forget the request).
pub fn take_request() -> bool {
    let word = addr_of_mut!(BOOT_REQUEST) as *mut u32;
    // SAFETY: volatile word accesses to this module's own `.uninit` static; any bit pattern
    // is a valid `u32`.
    let value = unsafe { core::ptr::read_volatile(word) };
    unsafe { core::ptr::write_volatile(word, 0) };
    boot_to_bootloader(value)
}

/// Jump to the ROM bootloader with the chip as after reset.
///
/// # Safety
/// Call first thing in `init`: no clock, peripheral or interrupt may have been configured
/// (RTIC has unmasked its interrupts in the NVIC; they are masked again here).
pub unsafe fn jump_to_bootloader() -> ! {
    cortex_m::interrupt::disable();
    let nvic = &*NVIC::PTR;
    for i in 0..8 {
        nvic.icer[i].write(0xFFFF_FFFF);
        nvic.icpr[i].write(0xFFFF_FFFF);
    }
    let scb = &*SCB::PTR;
    scb.vtor.write(h743::SYSTEM_BOOTLOADER_VECTORS);
    cortex_m::asm::dsb();
    cortex_m::asm::isb();
    // The ROM expects interrupts enabled as after reset; nothing is unmasked in the NVIC.
    cortex_m::interrupt::enable();
    cortex_m::asm::bootload(h743::SYSTEM_BOOTLOADER_VECTORS as *const u32)
}
