//! The `message_table!` macro: turns the id table in `messages.rs` into an enum with encode and
//! decode, so ids are written exactly once.

/// Why a valid frame did not become a message. The frame is dropped; nothing else changes.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum DecodeError {
    /// The id is not in this side's table (a newer peer?).
    UnknownId { id: u8 },
    /// The payload did not decode as the id's type, or had bytes left over.
    Malformed { id: u8 },
}

impl core::fmt::Display for DecodeError {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        match self {
            Self::UnknownId { id } => write!(f, "unknown message id 0x{id:02x}"),
            Self::Malformed { id } => write!(f, "malformed payload for message id 0x{id:02x}"),
        }
    }
}

#[cfg(feature = "std")]
impl std::error::Error for DecodeError {}

impl core::fmt::Display for crate::FrameError {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        match self {
            Self::Oversize => write!(f, "frame longer than {} bytes", crate::MAX_FRAME_LEN),
            Self::BadCobs => write!(f, "invalid COBS framing"),
            Self::TooShort { len } => write!(f, "frame of {len} bytes is too short"),
            Self::BadCrc { expected, actual } => {
                write!(f, "CRC mismatch (frame says {expected:08x}, data gives {actual:08x})")
            }
            Self::BadHeader => write!(f, "invalid frame header"),
        }
    }
}

#[cfg(feature = "std")]
impl std::error::Error for crate::FrameError {}

/// Declare a message enum from `id => Variant(Type)` lines.
macro_rules! message_table {
    (
        $(#[$meta:meta])*
        pub enum $name:ident {
            $( $(#[$vmeta:meta])* $id:literal => $variant:ident($ty:ty), )*
        }
    ) => {
        $(#[$meta])*
        #[derive(Clone, Debug, PartialEq)]
        pub enum $name {
            $( $(#[$vmeta])* $variant($ty), )*
        }

        impl $name {
            /// Every id in this table, in table order.
            pub const IDS: &'static [u8] = &[$($id),*];

            /// This message's id.
            pub fn id(&self) -> u8 {
                match self {
                    $( Self::$variant(_) => $id, )*
                }
            }

            /// Encode as one frame into `out`; returns the bytes written.
            pub fn encode(&self, seq: u16, out: &mut [u8]) -> Result<usize, $crate::EncodeError> {
                match self {
                    $( Self::$variant(body) => $crate::frame::encode($id, seq, body, out), )*
                }
            }

            /// Encode as one signed frame ([`crate::signing`]) into `out`; returns the bytes
            /// written.
            pub fn encode_signed(
                &self,
                seq: u16,
                signer: &$crate::Signer,
                timestamp: u64,
                out: &mut [u8],
            ) -> Result<usize, $crate::EncodeError> {
                match self {
                    $( Self::$variant(body) => {
                        $crate::frame::encode_signed($id, seq, body, signer, timestamp, out)
                    } )*
                }
            }

            /// Decode a checked frame.
            pub fn decode(frame: &$crate::Frame<'_>) -> Result<Self, $crate::DecodeError> {
                let id = frame.id;
                match id {
                    $( $id => {
                        let (body, rest) = postcard::take_from_bytes::<$ty>(frame.payload)
                            .map_err(|_| $crate::DecodeError::Malformed { id })?;
                        if !rest.is_empty() {
                            return Err($crate::DecodeError::Malformed { id });
                        }
                        Ok(Self::$variant(body))
                    } )*
                    _ => Err($crate::DecodeError::UnknownId { id }),
                }
            }
        }
    };
}

pub(crate) use message_table;
