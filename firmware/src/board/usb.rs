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
use usbd_serial::SerialPort;

use crate::app::hal::{Port, PortClosed};

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

/// The CDC-ACM serial link: the USB device and its serial class.
pub struct UsbSerial {
    device: UsbDevice<'static, Bus>,
    serial: SerialPort<'static, Bus, [u8; RX_BUFFER_BYTES], [u8; TX_BUFFER_BYTES]>,
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
        Self { device, serial }
    }

    /// Whether the host has configured the device (it is enumerated and can take data).
    pub fn is_configured(&self) -> bool {
        self.device.state() == UsbDeviceState::Configured
    }
}

/// The application's link pass reads and writes the CDC port through this.
impl Port for UsbSerial {
    /// Service the USB device (enumeration, control requests, endpoint events), then read what
    /// the host sent. Never blocks; the USB link never reports itself closed (a host that goes
    /// away stops reading, and the transmit buffer fills).
    fn read(&mut self, buffer: &mut [u8]) -> Result<usize, PortClosed> {
        // `false`: no new event; bytes of an earlier one may still wait in the class's buffer.
        let _ = self.device.poll(&mut [&mut self.serial]);
        Ok(self.serial.read(buffer).unwrap_or(0))
    }

    /// Offer `bytes` to the host; returns how many the CDC buffer took (0 when it is full or the
    /// host has not configured the device yet). Bytes not taken stay with the caller (the link
    /// server keeps them queued), so nothing is lost or reordered. Never blocks.
    fn write(&mut self, bytes: &[u8]) -> Result<usize, PortClosed> {
        if bytes.is_empty() || !self.is_configured() {
            return Ok(0);
        }
        // `WouldBlock`: the buffer is full, nothing taken. Other errors (bus trouble, the host
        // went away mid-transfer) also count as nothing taken, although usbd-serial may already
        // have buffered some of the bytes: the host may then see a repeated chunk, which its
        // frame decoder rejects (CRC) and resynchronises after.
        Ok(self.serial.write(bytes).unwrap_or(0))
    }

    /// Push buffered bytes into the IN endpoint. Never blocks; what does not fit goes next time.
    fn flush(&mut self) {
        let _ = self.serial.flush();
    }
}
