//! USB: a CDC-ACM serial port on the OTG2 peripheral's internal full-speed PHY (PA11/PA12, the
//! USB connector on H743 flight controllers and on the NUCLEO-H743ZI), clocked from HSI48.
//!
//! This module only moves bytes. Framing, the handshake and telemetry are the portable link
//! server's job (`crate::app`), so the simulator speaks exactly the same protocol.

use stm32h7xx_hal::usb_hs::{UsbBus, USB2};
use usb_device::bus::UsbBusAllocator;
use usb_device::device::{
    StringDescriptors, UsbDevice, UsbDeviceBuilder, UsbDeviceState, UsbVidPid,
};
use usb_device::UsbError;
use usbd_serial::SerialPort;

/// The USB bus of this board.
pub type Bus = UsbBus<USB2>;

/// Endpoint memory for the OTG driver, 32-bit words: 1024 words = 4 KiB, the OTG2 FIFO size
/// (`FIFO_DEPTH_WORDS` of stm32h7xx-hal's `USB2`). The CPU copies packets to and from it (no DMA),
/// so it may live in DTCM.
pub const EP_MEMORY_WORDS: usize = 1024;

/// CDC receive buffer, bytes: several 64-byte full-speed packets, so the host can send a whole
/// request frame while the USB task is busy.
const RX_BUFFER_BYTES: usize = 256;

/// CDC transmit buffer, bytes: room for several telemetry frames between two USB services.
const TX_BUFFER_BYTES: usize = 1024;

/// Bytes the USB task takes from the link server per chunk: one full-speed bulk packet.
pub const CHUNK_BYTES: usize = 64;

/// Manufacturer string descriptor.
pub const MANUFACTURER: &str = "airframe-learner";

/// Product string descriptor.
pub const PRODUCT: &str = "STM32H743 flight controller";

/// Static storage the USB stack borrows for the rest of the program (RTIC `#[init(local)]`).
pub struct UsbStorage {
    /// OTG endpoint memory.
    pub ep_memory: &'static mut [u32; EP_MEMORY_WORDS],
    /// The bus allocator the device and the serial class borrow.
    pub bus: &'static mut Option<UsbBusAllocator<Bus>>,
}

/// The CDC-ACM serial link: the USB device, its serial class, and the bytes the link server
/// produced that the endpoint has not accepted yet.
pub struct UsbSerial {
    device: UsbDevice<'static, Bus>,
    serial: SerialPort<'static, Bus, [u8; RX_BUFFER_BYTES], [u8; TX_BUFFER_BYTES]>,
    pending: [u8; CHUNK_BYTES],
    pending_start: usize,
    pending_end: usize,
}

impl UsbSerial {
    /// Enumerate as a CDC-ACM device with the project's VID/PID and `serial_number` (the chip's
    /// unique ID, [`crate::board::identity`], so several boards on one host can be told apart).
    pub fn new(usb: USB2, storage: UsbStorage, serial_number: &'static str) -> Self {
        let bus = storage.bus.insert(UsbBus::new(usb, storage.ep_memory));
        let serial = SerialPort::new_with_store(bus, [0; RX_BUFFER_BYTES], [0; TX_BUFFER_BYTES]);
        let device = UsbDeviceBuilder::new(bus, UsbVidPid(protocol::USB_VID, protocol::USB_PID))
            .strings(&[StringDescriptors::default()
                .manufacturer(MANUFACTURER)
                .product(PRODUCT)
                .serial_number(serial_number)])
            // One language, three strings: within usb-device's limits, so this cannot fail.
            .unwrap_or_else(|_| defmt::panic!("USB string descriptors rejected"))
            .device_class(usbd_serial::USB_CLASS_CDC)
            .build();
        Self { device, serial, pending: [0; CHUNK_BYTES], pending_start: 0, pending_end: 0 }
    }

    /// Service the USB device (enumeration, control requests, endpoint events), then hand every
    /// received byte to `on_bytes` in chunks. Never blocks.
    pub fn receive(&mut self, mut on_bytes: impl FnMut(&[u8])) {
        if !self.device.poll(&mut [&mut self.serial]) {
            return;
        }
        let mut chunk = [0u8; CHUNK_BYTES];
        while let Ok(count @ 1..) = self.serial.read(&mut chunk) {
            on_bytes(&chunk[..count]);
        }
    }

    /// Whether the host has configured the device (it is enumerated and can take data).
    pub fn is_configured(&self) -> bool {
        self.device.state() == UsbDeviceState::Configured
    }

    /// Move bytes from `fill` (which writes up to `buffer.len()` bytes and returns how many) to the
    /// host until `fill` has nothing more or the endpoint buffers are full. Bytes the endpoint did
    /// not accept are kept and sent first next time, so nothing is lost or reordered. Does nothing
    /// until the host has configured the device: the producer's own queue applies back-pressure.
    /// Never blocks.
    pub fn transmit(&mut self, mut fill: impl FnMut(&mut [u8]) -> usize) {
        if !self.is_configured() {
            return;
        }
        loop {
            if self.pending_start == self.pending_end {
                let produced = fill(&mut self.pending).min(CHUNK_BYTES);
                if produced == 0 {
                    break;
                }
                self.pending_start = 0;
                self.pending_end = produced;
            }
            match self.serial.write(&self.pending[self.pending_start..self.pending_end]) {
                Ok(written) => self.pending_start += written,
                Err(UsbError::WouldBlock) => break,
                Err(_) => {
                    // A bus error (e.g. the host went away mid-transfer): drop this chunk. The
                    // host's frame decoder resynchronises at the next frame delimiter.
                    self.pending_start = self.pending_end;
                    break;
                }
            }
        }
        // Push what is buffered into the endpoint; WouldBlock only means "more next time".
        let _ = self.serial.flush();
    }
}
