// Signal K server plugin (docs/marine.md): the NMEA 0183 parser of Signal K (@signalk/nmea0183-signalk) has no
// XDR hook, so attitude sent as XDR reaches navigation.attitude only through a plugin that registers one. This
// plugin reads the layout Airmar heading sensors, Signal K's own NMEA 0183 output (signalk-to-nmea0183, XDRNA)
// and ahrsd send: quadruples (type, value, unit, name) with type A (angular displacement), unit D (degrees),
// name PTCH (pitch, bow up positive) or ROLL (roll, starboard down positive) -- Signal K's signs, in radians.
module.exports = (app) => {
  const plugin = {
    id: 'ahrsd-xdr-attitude',
    name: 'XDR pitch/roll to navigation.attitude',
    description: 'Parses NMEA 0183 XDR A/D PTCH and ROLL transducers into navigation.attitude',
    schema: { type: 'object', properties: {} }
  }

  const parser = ({ parts, tags }) => {
    const attitude = {}
    for (let i = 0; i + 3 < parts.length; i += 4) {
      if (parts[i] !== 'A' || parts[i + 2] !== 'D' || parts[i + 1] === '') continue
      const radians = (Number(parts[i + 1]) * Math.PI) / 180
      if (parts[i + 3] === 'PTCH') attitude.pitch = radians
      if (parts[i + 3] === 'ROLL') attitude.roll = radians
    }
    if (Object.keys(attitude).length === 0) return null
    return {
      updates: [{ source: tags.source, timestamp: tags.timestamp,
        values: [{ path: 'navigation.attitude', value: attitude }] }]
    }
  }

  plugin.start = () => {
    app.emitPropertyValue('nmea0183sentenceParser', { sentence: 'XDR', parser })
  }
  plugin.stop = () => {}
  return plugin
}
