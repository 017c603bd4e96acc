//! The camera transport: the three pipes of a USB Still Image device, as byte transfers.

use std::io;

use async_trait::async_trait;
use tokio::sync::mpsc;

/// The pipes of a PTP camera (USB Still Image Capture class: bulk-out carries commands and
/// host data, bulk-in camera data and responses, interrupt-in events). Each call moves one
/// transfer; containers may span transfers (the backend reassembles them with
/// [`btfrig_protocols::ptp::ContainerDecoder`]). The receiving calls wait without a timeout
/// and must be cancel-safe: the backend bounds them with the rig clock.
#[async_trait]
pub trait PtpTransport: Send {
    /// Sends bytes on bulk-out.
    async fn bulk_out(&mut self, bytes: Vec<u8>) -> io::Result<()>;
    /// The next bulk-in transfer. An error means the camera is gone.
    async fn bulk_in(&mut self) -> io::Result<Vec<u8>>;
    /// The next interrupt-in transfer (an event). An error means the camera is gone.
    async fn interrupt_in(&mut self) -> io::Result<Vec<u8>>;
    /// Resets the pipes after a loss or a stale exchange (USB: clear halt; device reset).
    async fn reset(&mut self) -> io::Result<()>;
    /// What this is connected to, for messages.
    fn describe(&self) -> String;
}

/// An in-process transport: the host end of three channels whose other end is a
/// responder ([`crate::responder::PtpResponder`]).
pub struct ChannelTransport {
    pub(crate) out: mpsc::UnboundedSender<Vec<u8>>,
    pub(crate) bulk: mpsc::UnboundedReceiver<Vec<u8>>,
    pub(crate) events: mpsc::UnboundedReceiver<Vec<u8>>,
    pub(crate) name: String,
}

fn gone() -> io::Error {
    io::Error::new(io::ErrorKind::NotConnected, "camera responder gone")
}

#[async_trait]
impl PtpTransport for ChannelTransport {
    async fn bulk_out(&mut self, bytes: Vec<u8>) -> io::Result<()> {
        self.out.send(bytes).map_err(|_| gone())
    }

    async fn bulk_in(&mut self) -> io::Result<Vec<u8>> {
        self.bulk.recv().await.ok_or_else(gone)
    }

    async fn interrupt_in(&mut self) -> io::Result<Vec<u8>> {
        self.events.recv().await.ok_or_else(gone)
    }

    async fn reset(&mut self) -> io::Result<()> {
        // Drop whatever is queued, as a pipe reset does.
        while self.bulk.try_recv().is_ok() {}
        while self.events.try_recv().is_ok() {}
        Ok(())
    }

    fn describe(&self) -> String {
        format!("in-process PTP responder ({})", self.name)
    }
}
